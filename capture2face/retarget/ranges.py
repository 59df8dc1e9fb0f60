"""Each ARKit character at its own range: the expression pairs' targets from the actor's
motion, scaled by how far the character's own morphs move them.

The feature-point network maps the actor's landmarks onto the character's; how far a
mapped point moves is the network's local stretch, set by where the two faces' landmarks
sit, not by what the character's morphs can do. A Ready Player Me head's ``browInnerUp``
at 1 raises its inner brows 0.13 inter-ocular distances (IOD), an ICT scan's 0.05: mapped
brow motion of a human's size asked for 0.36 of it, and the solve made up the rest of the
forehead's motion by setting ``browDown`` against it (0.68 where the actor never frowns).
Its lips part 0.38 IOD at ``jawOpen`` 1, but the network, stretched by the head's thin
lips, mapped a full opening to 0.67 of the actor's amplitude.

So each expression pair's separation (:data:`RANGE_PAIRS` of
:data:`~capture2face.retarget.arkit_solve.EXPRESSION_PAIRS`: the lips' gap columns, the
mouth's width, each brow against its eye) is given its target directly: the actor's
change of that separation in its own IOD, times the character's IOD, times the ratio of
the character's range (its morphs at 1, measured at load from the solve's model) to a
human's (:data:`REFERENCE_RANGE`). The actor's full raise lands on the character's full
raise, whatever its morphs' size; a head with a human's range follows the actor's motion
in proportion to its face. The lids keep the network's motion (their measure is relative
to the eye's own opening, which the network keeps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.retarget.arkit_solve import EXPRESSION_PAIRS, MorphSolve
from capture2face.topology import IOD_PAIR

#: Indices into EXPRESSION_PAIRS whose separation is mapped onto the character's range.
RANGE_PAIRS = np.arange(6, 16)

#: (up, down) change of each EXPRESSION_PAIRS separation (IOD) at the morph that moves it
#: most, on ICT-FaceKit's generic neutral (ict-a.glb): a human's morphs at 1. Rows 0-5 (the
#: lids) are not used.
REFERENCE_RANGE = np.array([
    [0.031, 0.103], [0.032, 0.088], [0.028, 0.089], [0.031, 0.104], [0.032, 0.092], [0.027, 0.090],
    [0.360, 0.425], [0.330, 0.411], [0.336, 0.414], [0.079, 0.106],
    [0.065, 0.021], [0.048, 0.032], [0.052, 0.028], [0.065, 0.022], [0.049, 0.033], [0.044, 0.025],
])

#: Bounds of the range ratio (a character a quarter or four times a human's size).
RATIO_BOUNDS = (0.25, 4.0)
#: The mouth's width (row 9 of EXPRESSION_PAIRS) is widened at most this much past the
#: actor's, in proportion to the face: a smile morph that widens a mouth much further than a
#: human's (Ready Player Me's XR head) is the character's style, and passed through whole
#: it took every wide smile past the actor's; capped at the actor's (1.0), the solve made the
#: smile of other morphs (docs/characters.md).
WIDTH_PAIR, WIDTH_RATIO_MAX = 9, 1.15

#: Each brow's measured pair (its mid brow against the eye's outer corner, as the fidelity
#: measures and the tracked-back brows read it) and its inner and outer pairs.
BROW_SIDES = {10: (11, 12), 13: (14, 15)}
#: A head whose brow morphs raise its inner or outer brow this many times more than its mid
#: brow, each against a human's, has brows of another shape: a Ready Player Me's
#: ``browInnerUp`` raises its inner brow 2.7-3.2 times a human's and its outer brow raise its
#: mid 0.85-1.15 times (2.5-3.8 apart; an ICT scan's 0.98-1.07 each). Each pair scaled by its
#: own morph's ratio, the three targets disagree (the actor's inner brow asks ``browInnerUp``
#: at 1 where its mid brow asks for a third of what that raises), and the solve, splitting the
#: difference, followed the mid brow at r 0.82-0.89 (docs/characters.md). Where such a head's
#: full raise (every morph that raises the mid brow, together) passes :data:`BROW_RATIO_MAX`
#: of a human's, the inner and outer pairs weigh :data:`BROW_SIDE_WEIGHT` of a pair and the
#: mid pair follows the actor's at :data:`BROW_RATIO_MAX` (as the mouth's width: the head's
#: style past a human's is not passed through whole).
BROW_SHAPE_RATIO, BROW_SIDE_WEIGHT, BROW_RATIO_MAX = 2.0, 0.5, 1.15


@dataclass
class RangeTargets:
    """The ranged pairs' targets of an ARKit character's solve.

    Attributes:
        rows: (R,) model points (N + k) of the ranged pairs.
        components: (R,) the separation's component in each pair's frame: 0 (along the
            rest direction), or 1 (vertical) for a pair touching at rest (the lips).
        ends: (R, 2) slots (into the N landmarks) of each pair's two points.
        rest: (R,) the component at the character's rest.
        gain: (R, 2) the character's range over a human's, (up, down).
        actor_rest: (R,) each pair's separation on the actor's neutral.
        scale: the character's IOD over the actor's.
        weights: (R,) each ranged pair's weight in the solve against an expression pair's
            (below 1 for a brow's inner and outer pairs where its shape differs from a
            human's, :data:`BROW_SHAPE_RATIO`).
    """

    rows: np.ndarray
    components: np.ndarray
    ends: np.ndarray
    rest: np.ndarray
    gain: np.ndarray
    actor_rest: np.ndarray
    scale: float
    weights: np.ndarray | None = None

    def apply(self, model_points: np.ndarray, actor: np.ndarray, fixed: np.ndarray) -> np.ndarray:
        """``model_points`` (k, N + K, 3) with the ranged components set from ``actor`` (k, N, 3),
        the actor's landmarks; ``fixed`` (k, R): the curve-only morphs' part of each
        component, which the solved morphs do not explain."""
        sep = np.linalg.norm(actor[:, self.ends[:, 0]] - actor[:, self.ends[:, 1]], axis=-1) - self.actor_rest
        gain = np.where(sep > 0, self.gain[:, 0], self.gain[:, 1])
        out = model_points.copy()
        out[:, self.rows, self.components] = self.rest + self.scale * gain * sep - fixed
        return out

    def components_of(self, model_points: np.ndarray) -> np.ndarray:
        """(k, R) the ranged components of ``model_points`` (k, N + K, 3)."""
        return model_points[:, self.rows, self.components]


def character_ranges(solve: MorphSolve, components: np.ndarray, iod: float, poses: np.ndarray | None = None
                     ) -> np.ndarray:
    """(K, 2) (up, down) IOD: the largest change of each of the solve's pairs (its
    ``components`` (K,)) that one of its solved morphs makes at 1, or with ``poses``
    (Q, Ms) weights of the solved morphs, one of those poses."""
    n = len(solve.model.rest) - len(solve.pairs)
    nf = solve.model.n_free_vars
    rows = solve.model.matrix[3 * n + 3 * np.arange(len(solve.pairs)) + components, nf:] / iod
    if poses is not None:
        rows = rows @ np.asarray(poses, np.float64).T
    if rows.shape[1] == 0:
        return np.zeros((len(solve.pairs), 2))
    return np.stack([np.maximum(rows.max(1), 0.0), np.maximum(-rows.min(1), 0.0)], 1)


def range_targets(solve: MorphSolve, landmarks: np.ndarray, actor_neutral: np.ndarray) -> RangeTargets | None:
    """The :class:`RangeTargets` of ``solve`` at ``landmarks`` (N,), ``actor_neutral``
    (N, 3) the actor's neutral the network maps from; None without the eyes' corners."""
    slot = {int(lm): i for i, lm in enumerate(landmarks)}
    if not all(lm in slot for lm in IOD_PAIR):
        return None
    present = [k for k, (a, b) in enumerate(EXPRESSION_PAIRS) if int(a) in slot and int(b) in slot]
    n = len(landmarks)
    rest = solve.model.rest
    iod = float(np.linalg.norm(rest[slot[IOD_PAIR[0]]] - rest[slot[IOD_PAIR[1]]]))
    actor_iod = float(np.linalg.norm(actor_neutral[slot[IOD_PAIR[0]]] - actor_neutral[slot[IOD_PAIR[1]]]))
    frames = solve.pair_frames
    touching = (np.array([np.allclose(f, np.eye(3)) for f in frames]) if frames is not None
                else np.ones(len(present), bool))
    components = np.where(touching, 1, 0)
    ranges = character_ranges(solve, components, iod)
    keep = np.flatnonzero(np.isin(present, RANGE_PAIRS))
    if not len(keep) or iod <= 0 or actor_iod <= 0:
        return None
    reference = REFERENCE_RANGE[np.asarray(present)[keep]]
    gain = np.clip(ranges[keep] / reference, *RATIO_BOUNDS)
    if solve.full_poses is not None:
        # A convention's mix (a viseme head's open visemes together) reaches what no one
        # morph does, up to a human's range: past it the width is the recipe's, not the head's.
        mixed = np.minimum(character_ranges(solve, components, iod, solve.full_poses)[keep] / reference, 1.0)
        gain = np.maximum(gain, mixed)
    width = np.asarray(present)[keep] == WIDTH_PAIR
    gain[width] = np.minimum(gain[width], WIDTH_RATIO_MAX)
    weights = brow_shape(gain, np.asarray(present)[keep], full_raise(solve, components, iod)[keep] / reference[:, 0])
    ends = solve.pairs[keep]
    return RangeTargets(
        rows=n + keep, components=components[keep], ends=ends,
        rest=rest[n + keep, components[keep]], gain=gain,
        actor_rest=np.linalg.norm(actor_neutral[ends[:, 0]] - actor_neutral[ends[:, 1]], axis=-1),
        scale=iod / actor_iod, weights=weights,
    )


def full_raise(solve: MorphSolve, components: np.ndarray, iod: float) -> np.ndarray:
    """(K,) IOD: how far each of the solve's pairs (its ``components`` (K,)) grows with every
    solved morph that grows it at 1 together (a brow's inner and outer raise)."""
    n = len(solve.model.rest) - len(solve.pairs)
    rows = solve.model.matrix[3 * n + 3 * np.arange(len(solve.pairs)) + components, solve.model.n_free_vars:] / iod
    return np.maximum(rows, 0.0).sum(1)


def brow_shape(gain: np.ndarray, pairs: np.ndarray, raise_ratio: np.ndarray) -> np.ndarray:
    """(R,) the ranged pairs' weights (:data:`BROW_SHAPE_RATIO`): 1, or on a head whose brows
    differ from a human's in shape and rise further (``raise_ratio`` (R,): each pair's full
    raise over a human's) :data:`BROW_SIDE_WEIGHT` for that brow's inner and outer pairs, its
    mid pair's rise (``gain`` (R, 2), updated) then :data:`BROW_RATIO_MAX`. ``pairs``: (R,)
    rows of EXPRESSION_PAIRS."""
    weights = np.ones(len(pairs))
    row = {int(p): k for k, p in enumerate(pairs)}
    for mid, sides in BROW_SIDES.items():
        if mid not in row or not all(s in row for s in sides):
            continue
        m, others = row[mid], [row[s] for s in sides]
        if gain[others, 0].max() > BROW_SHAPE_RATIO * gain[m, 0] and raise_ratio[m] > BROW_RATIO_MAX:
            weights[others] = BROW_SIDE_WEIGHT
            gain[m, 0] = BROW_RATIO_MAX
    return weights

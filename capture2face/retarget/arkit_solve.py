"""Dutreve's retargeting onto an ARKit character (ARKit-named morphs, no face bones).

The feature-point network maps the actor's landmarks onto the character's landmark points
(as for any rig); the character's morph weights are then solved, bounded to [0, 1], so
that its landmark points follow the mapped ones (:mod:`capture2face.retarget.solve`,
morphs only: the model is :func:`~capture2face.rig.feature_points.landmark_basis`).

The clip's ARKit curves (:func:`~capture2face.retarget.arkit.arkit_curves`) are the prior:

* morphs the feature points cannot see take their curve as it is (:data:`CURVE_ONLY`: the
  cheeks' puff, the lips' roll, the tongue, the eyes' look morphs, whose lid motion is
  the gaze's and not an expression; and any morph that moves no landmark by more than
  ``min_motion`` inter-ocular distances); their motion is taken off the mapped points
  before the solve, so the solved morphs explain only the rest;
* the solved morphs are pulled towards their curves, ``strength |w - curve|^2`` (in
  the fit's units, cm^2): where several morphs could explain the same landmark motion
  (a smile or a cheek squint), the one the tracker's scores name wins.

What is fitted: the landmark points, those on the features' contours
(:data:`FEATURE_CONTOURS`) weighing most, and the differences of the
:data:`EXPRESSION_PAIRS` (lids, lips, mouth corners, brows against the eyes), whose motion
a morph basis shaped for the whole face would otherwise trade for the many points around
them. Six unbounded unknowns take the rigid head motion that the pose removal leaves in
the landmarks (:func:`rigid_columns`: the default avatar's bones follow it, no morph
can); they are solved and dropped. The network's output is steadied by the two faces'
similarity (:class:`SteadiedMap`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.maths.rotations import similarity
from capture2face.retarget.solve import LinearRigModel
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.feature_points import landmark_basis
from capture2face.rig.morph_conventions import convention_channels, convention_recipes, mix_morphs, recipe_poses
from capture2face.topology import (
    BROW_HEIGHT_PAIRS,
    BROWS,
    EYE_LEFT,
    EYE_RIGHT,
    LIDS_LEFT,
    LIDS_RIGHT,
    LIP_GAP,
    LIPS_INNER,
    LIPS_OUTER,
    MOUTH_CORNERS,
    NOSE_WINGS,
)

#: ARKit morphs driven by their curves alone: the tracker's landmarks do not show them
#: (a puffed cheek, a rolled lip, the tongue) or show them as something else (the eyes'
#: look morphs move the lids with the gaze).
CURVE_ONLY = frozenset({
    "cheekPuff", "tongueOut", "mouthRollLower", "mouthRollUpper",
    "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight",
    "eyeLookOutLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight",
})


#: ARKit morphs that move the same features in opposite directions (a brow raised or
#: lowered, the mouth or jaw sideways): set together they cancel, so the landmarks cannot
#: tell a still brow from both at once, and a morph basis shaped unlike a human's (a Ready
#: Player Me head's ``browDown`` also pulls the brows in) trades them to fit what neither
#: shows alone. Their co-activation is penalised. Left out, because the solve then traded
#: other morphs instead: the lids (an ICT head's ``eyeWide`` also lifts the brows, and the
#: brows lost range), the pucker against the smile (the smile dropped), ``jawOpen`` against
#: ``mouthClose`` (``mouthLowerDown`` opened the mouth instead of the jaw); figures in
#: docs/characters.md.
ANTAGONISTS = (
    ("browInnerUp", "browDownLeft"), ("browInnerUp", "browDownRight"),
    ("browOuterUpLeft", "browDownLeft"), ("browOuterUpRight", "browDownRight"),
    ("mouthLeft", "mouthRight"), ("jawLeft", "jawRight"),
)

#: Lid morphs that are antagonists on some heads only, penalised as :data:`ANTAGONISTS` where
#: they move the eye's contour against each other (the cosine of their motions below
#: :data:`LID_OPPOSITION`). A Ready Player Me head's ``eyeWide`` opens both lids, the lower
#: as far as the upper (cosine -0.63 to -0.67 with ``eyeSquint``, -0.36 to -0.38 with
#: ``cheekSquint``): ``eyeWide`` + ``eyeSquint`` at 1 is its upper lid raised alone, and the
#: solve made every brow raise's lid lift of both at 1 (p99 1.00 where the curves reach
#: 0.05-0.51). An ICT head's ``eyeWide`` moves the upper lid only (cosines -0.17 to 0.02):
#: there the pairs are none, and its lids keep the solve measured in docs/characters.md.
LID_ANTAGONISTS = (
    ("eyeWideLeft", "eyeSquintLeft"), ("eyeWideRight", "eyeSquintRight"),
)
LID_OPPOSITION = -0.3

#: Mouth morphs that are antagonists on some heads only, penalised as :data:`ANTAGONISTS`
#: where they move the lips' contours against each other (the cosine of their motions below
#: :data:`MOUTH_OPPOSITION`). ``mouthFunnel`` draws the corners in and forward and lifts the
#: upper lip, ``mouthStretch`` pulls the corners out and back: on a Ready Player Me head
#: (cosines -0.60 to -0.62) the solve made d18's grimace of both (funnel 0.52, stretch
#: 0.95 / 0.94 where the curves show 0.01 and 0.02-0.05), the stretch undoing the funnel's
#: narrowing. An ICT head's pair is less opposed (-0.49 / -0.50); penalised there too, its
#: mouth gains fell 0.01 (docs/characters.md), so its solve keeps no pair.
MOUTH_ANTAGONISTS = (
    ("mouthFunnel", "mouthStretchLeft"), ("mouthFunnel", "mouthStretchRight"),
)
MOUTH_OPPOSITION = -0.55


#: MediaPipe's contours of the features (lips, eyes, brows, the nose's wings): the points an
#: expression moves (the rest, the cheeks, forehead and silhouette, carry the tracker's
#: noise as much).
FEATURE_CONTOURS = np.array([*LIPS_OUTER, *LIPS_INNER, *EYE_LEFT, *EYE_RIGHT, *BROWS, *NOSE_WINGS])
#: The eyes' contours (both lids): their motion is the network's (:class:`SteadiedMap`).
EYE_CONTOURS = FEATURE_CONTOURS[40:72]
#: The lips' contours (outer and inner).
LIP_CONTOURS = FEATURE_CONTOURS[:40]
#: Landmark pairs whose relative motion is an expression: the lids apart (three columns per
#: eye), the inner lips apart (three columns), the mouth's corners, each brow (inner, middle,
#: outer) against its eye's corners. Fitted as extra points (the pair's difference), so a
#: global morph basis does not trade them for the many points around them.
EXPRESSION_PAIRS = np.array([
    LIDS_RIGHT, (158, 153), (160, 144), LIDS_LEFT, (385, 380), (387, 373),
    LIP_GAP, (82, 87), (312, 317), MOUTH_CORNERS,
    BROW_HEIGHT_PAIRS[0], (107, 133), (70, 33), BROW_HEIGHT_PAIRS[1], (336, 362), (300, 263),
])


#: Each eye's lid columns (rows of :data:`EXPRESSION_PAIRS`: the middle, the measured one,
#: then its two sides) and the morph that closes them.
LID_COLUMNS = (((0, 1, 2), "eyeBlinkRight"), ((3, 4, 5), "eyeBlinkLeft"))
#: A human's blink closes the three columns by the same share of their opening (ICT heads:
#: 0.82-0.87, each side within 0.04 of the middle). A head whose blink closes a side column
#: more than this much further or less far than its middle (Ready Player Me's XR head: the
#: inner column 0.99, the middle 0.80, the outer 0.88) has lids of another shape; where its
#: blink also shuts each column at least :data:`LID_SHUT` of its opening, the side columns'
#: closing is mapped onto that shape (:meth:`MorphSolve.lid_targets`).
LID_SHAPE_TOLERANCE, LID_SHUT = 0.1, 0.75


#: Inter-ocular distances: a pair closer at rest is fitted in full (:func:`pair_frames`):
#: the inner lips, 0.03-0.063 apart on the shared heads. Open lids are 0.085 (Rocketbox) to
#: 0.147 apart: at 0.1 Rocketbox's lids were fitted in full, their sideways and depth slide
#: held its lid separations back (eye gain 0.75-0.77 on d12, 0.89-1.02 framed).
MIN_PAIR_SEPARATION = 0.075


@dataclass
class MorphSolve:
    """The linear model of an ARKit character's landmark points.

    Attributes:
        model: rest (N, 3) and d(points)/d(w) of the solved morphs (``model.morphs``).
        fixed: (Mf,) morphs that take their curve (:data:`CURVE_ONLY`, or moving no
            landmark; a morph without an ARKit name has a curve of 0).
        fixed_deltas: (Mf, N, 3) their landmark deltas.
        pairs: (K, 2) slots (into the N landmarks) of the :data:`EXPRESSION_PAIRS` the rig
            has: the model's points are the N landmarks, then the K differences.
        pair_frames: (K, 3, 3) each difference's operator (:func:`pair_frames`), or None.
        antagonists: (P, 2) unknowns (columns of ``model.matrix``) of the solved morphs'
            :data:`ANTAGONISTS`.
        twins: (T, 2) (fixed morph, solved morph) of a head of another convention: a morph
            that moves no landmark takes the weight solved for its recipe's twin (Rocketbox's
            teeth follow its jaw), not the recipe's.
        full_poses: (52, Ms) on a head of another convention, the solved morphs' weights at
            each ARKit curve's recipe at 1 (a viseme set's widest mouth is its open visemes
            together: its range, :mod:`capture2face.retarget.ranges`); None on an ARKit head.
        mix: (G,) the lips' shapes of a convention authored as a mix (a viseme set's,
            :func:`~capture2face.rig.morph_conventions.mix_morphs`), solved or fixed, whose
            sum a solve may cap (:func:`mix_cap`); None without.
        lid_ratios: (K,) each pair's closing at its eye's blink over the eye's middle column's
            (1 off the side lid columns), where the head's lids are of another shape
            (:func:`lid_ratios`); None where they close as a human's.
    """

    model: LinearRigModel
    fixed: np.ndarray
    fixed_deltas: np.ndarray
    pairs: np.ndarray
    pair_frames: np.ndarray | None = None
    antagonists: np.ndarray | None = None
    full_poses: np.ndarray | None = None
    twins: np.ndarray | None = None
    mix: np.ndarray | None = None
    lid_ratios: np.ndarray | None = None

    def mix_unknowns(self) -> np.ndarray | None:
        """(G',) unknowns (columns of ``model.matrix``) of the ``mix``'s solved morphs."""
        if self.mix is None:
            return None
        return self.model.n_free_vars + np.flatnonzero(np.isin(self.model.morphs, self.mix))

    def points(self, landmark_points: np.ndarray) -> np.ndarray:
        """(..., N + K, 3) the model's points of (..., N, 3) landmark points."""
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        diff = landmark_points[..., a, :] - landmark_points[..., b, :]
        if self.pair_frames is not None:
            diff = np.einsum("kij,...kj->...ki", self.pair_frames, diff)
        return np.concatenate([landmark_points, diff], -2)

    def lid_targets(self, model_points: np.ndarray) -> np.ndarray:
        """(..., N + K, 3) ``model_points`` with each side lid column's closing (its
        component along its rest direction, below rest) times its :attr:`lid_ratios`, up to
        shut: the actor's closing on the head's own lid shape. Unchanged without ratios.

        Why: the network maps the actor's lids, whose columns close together, onto the
        head's; where the head's blink closes its inner column 0.99 of the way and its middle
        0.80, no blink weight fits both, and the solve held the blink at 0.56-0.61 (curves
        0.91-0.92, d12) with ``eyeSquint`` standing in: the middle, the eye's measured
        opening, closed 0.8 of the actor's way (docs/characters.md)."""
        if self.lid_ratios is None:
            return model_points
        rows = len(model_points[0]) - len(self.pairs) + np.flatnonzero(self.lid_ratios != 1.0)
        ratio = self.lid_ratios[self.lid_ratios != 1.0]
        rest = self.model.rest[rows, 0]
        closing = 1.0 - model_points[..., rows, 0] / rest
        out = model_points.copy()
        out[..., rows, 0] = np.where(closing > 0, rest * (1.0 - np.minimum(closing * ratio, 1.0)),
                                     model_points[..., rows, 0])
        return out


def pair_frames(rest_diff: np.ndarray, across: float, min_separation: float) -> np.ndarray:
    """(K, 3, 3) operators taking a pair's difference (K pairs, ``rest_diff`` (K, 3) at
    rest) to (its component along its rest direction, ``across`` times the two across it);
    the identity for a pair closer than ``min_separation`` at rest (touching lips: no
    direction to speak of).

    A pair's separation is the expression (the lids', a brow's height above its eye, the
    mouth's width); how its two points slide across each other is where a character's
    morphs and the tracker's landmarks disagree most (an ICT head's blink moves its upper
    lid's landmark sideways against the lower's), and fitting it in full held the
    separations back (brow and eye gains 0.64-0.79 instead of 0.8-1.1 on the ICT heads)."""
    dist = np.linalg.norm(rest_diff, axis=1, keepdims=True)
    u = rest_diff / np.maximum(dist, 1e-9)
    helper = np.where(np.abs(u[:, [0]]) < 0.9, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    v = np.cross(u, helper)
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
    w = np.cross(u, v)
    frames = np.stack([u, across * v, across * w], 1)
    frames[dist[:, 0] < min_separation] = np.eye(3)
    return frames


def expression_pairs(landmarks: np.ndarray) -> np.ndarray:
    """(K, 2) slots into ``landmarks`` (N,) of the :data:`EXPRESSION_PAIRS` it holds."""
    slot = {int(lm): i for i, lm in enumerate(landmarks)}
    return np.array([(slot[a], slot[b]) for a, b in EXPRESSION_PAIRS if a in slot and b in slot],
                    np.int64).reshape(-1, 2)


def arkit_point_weights(landmarks: np.ndarray, landmark_weights: np.ndarray, other: float, pair: float) -> np.ndarray:
    """(N + K,) a-priori weights of the model's points: ``landmark_weights`` (N,) times
    ``other`` off the :data:`FEATURE_CONTOURS`, then ``pair`` for each expression pair."""
    w = np.where(np.isin(landmarks, FEATURE_CONTOURS), 1.0, other) * landmark_weights
    return np.concatenate([w, np.full(len(expression_pairs(landmarks)), pair)])


def morph_solve(rig, landmarks: np.ndarray, min_motion: float, across: float = 1.0) -> MorphSolve:
    """Split the rig's morphs into solved and curve-only ones at ``landmarks`` (N,).

    Args:
        min_motion: inter-ocular distances; a morph whose largest landmark motion is below
            it is curve-only.
        across: weight (of the residual, not squared) of an expression pair's difference
            across its rest direction against along it (:func:`pair_frames`).
    """
    rest, deltas = landmark_basis(rig, landmarks)
    motion = np.linalg.norm(deltas, axis=2).max(1) if len(landmarks) else np.zeros(rig.n_morphs)
    channels = solve_channels(rig.morph_names)
    fixed = np.array([bool(channels.get(m)) and set(channels[m]) <= CURVE_ONLY
                      or motion[m] < min_motion * rig.interocular() for m in range(rig.n_morphs)], bool)
    # Only the driven morphs are solved (ARKit-named, or a convention's with a recipe): others
    # (an ARKit head's visemes, a character's extras) have no curve to say which of two
    # look-alike shapes is meant, and stay 0.
    solved = np.flatnonzero(~fixed & np.isin(np.arange(rig.n_morphs), list(channels)))
    named = {m: c[0] for m, c in channels.items() if len(c) == 1}
    pairs = expression_pairs(landmarks)
    out = MorphSolve(model=None, fixed=np.flatnonzero(fixed), fixed_deltas=deltas[fixed],
                     pairs=pairs, pair_frames=pair_frames(rest[pairs[:, 0]] - rest[pairs[:, 1]], across,
                                                        MIN_PAIR_SEPARATION * rig.interocular()))
    n = len(landmarks)
    columns = np.concatenate([rigid_columns(rest), deltas[solved].reshape(len(solved), -1).T], 1)  # (3N, 6 + Ms)
    # Each column is a motion of the N points: its pair differences follow from it.
    matrix = np.moveaxis(out.points(np.moveaxis(columns.reshape(n, 3, -1), -1, 0)), 0, -1).reshape(-1, columns.shape[1])
    out.model = LinearRigModel(rest=out.points(rest), matrix=matrix, free_bones=np.zeros(0, np.int64),
                               morphs=solved, n_rigid=6)
    eyes, lips = deltas[:, np.isin(landmarks, EYE_CONTOURS)], deltas[:, np.isin(landmarks, LIP_CONTOURS)]
    pairs = (ANTAGONISTS + opposed_pairs(named, eyes, LID_ANTAGONISTS, LID_OPPOSITION)
             + opposed_pairs(named, lips, MOUTH_ANTAGONISTS, MOUTH_OPPOSITION))
    out.antagonists = antagonist_unknowns(named, solved, out.model.n_free_vars, pairs)
    if not arkit_morphs(rig.morph_names):
        out.full_poses = recipe_poses(rig.morph_names)[:, solved]
        out.twins = recipe_twins(rig.morph_names, out.fixed, solved)
        mix = mix_morphs(rig.morph_names)
        out.mix = mix if len(mix) else None
    out.lid_ratios = lid_ratios(out, named, landmarks)
    return out


def mix_cap(solve: MorphSolve, prior: np.ndarray, cap: float | None) -> np.ndarray | None:
    """(F,) the most the solved morphs of ``solve.mix`` may sum to per frame: ``cap`` less
    the mix's fixed morphs' weights in ``prior`` (F, M); None without a mix or a cap."""
    if solve.mix is None or cap is None:
        return None
    fixed = solve.mix[np.isin(solve.mix, solve.fixed)]
    return np.maximum(cap - prior[:, fixed].sum(1, dtype=np.float64), 0.0)


def lid_ratios(solve: MorphSolve, named: dict[int, str], landmarks: np.ndarray) -> np.ndarray | None:
    """(K,) :attr:`MorphSolve.lid_ratios` of ``solve`` at ``landmarks`` (N,), ``named``:
    {morph: ARKit name}: each side lid column's closing at its eye's blink (each column's
    along its rest direction, as a share of its rest) over the middle column's, for each eye
    whose blink closes them unevenly (:data:`LID_SHAPE_TOLERANCE`) and shuts each at least
    :data:`LID_SHUT`; 1 for the other pairs. None where no eye is such."""
    slot = {int(lm): i for i, lm in enumerate(landmarks)}
    row_of = {int(r): k for k, r in enumerate(r for r, (a, b) in enumerate(EXPRESSION_PAIRS)
                                               if int(a) in slot and int(b) in slot)}
    column = {named.get(int(m)): j for j, m in enumerate(solve.model.morphs)}
    n, nf = len(landmarks), solve.model.n_free_vars
    out = np.ones(len(solve.pairs))
    for rows, blink in LID_COLUMNS:
        if blink not in column or not all(r in row_of for r in rows):
            continue
        k = np.array([row_of[r] for r in rows])
        along = solve.model.rest[n + k, 0]
        if solve.pair_frames is not None and any(np.allclose(solve.pair_frames[j], np.eye(3)) for j in k):
            continue  # a pair fitted in full: its first component is not its opening
        shut = -solve.model.matrix[3 * (n + k), nf + column[blink]] / np.maximum(along, 1e-9)
        if shut.min() >= LID_SHUT and np.abs(shut[1:] / shut[0] - 1.0).max() > LID_SHAPE_TOLERANCE:
            out[k[1:]] = shut[1:] / shut[0]
    return out if np.any(out != 1.0) else None


def opposed_pairs(named: dict[int, str], deltas: np.ndarray, pairs: tuple[tuple[str, str], ...],
                  threshold: float) -> tuple[tuple[str, str], ...]:
    """The ``pairs`` (ARKit names) whose morphs move the points of ``deltas`` (M, P, 3), each
    morph's motion of P contour points, against each other (cosine below ``threshold``);
    ``named``: {morph: ARKit name}. A pair whose name stands for several morphs is judged on
    the first."""
    morph: dict[str, int] = {}
    for m, name in named.items():
        morph.setdefault(name, m)
    out = []
    for a, b in pairs:
        if a not in morph or b not in morph:
            continue
        da, db = deltas[morph[a]].ravel(), deltas[morph[b]].ravel()
        norm = float(np.linalg.norm(da) * np.linalg.norm(db))
        if norm > 0 and float(da @ db) / norm < threshold:
            out.append((a, b))
    return tuple(out)


def recipe_twins(morph_names: list[str], fixed: np.ndarray, solved: np.ndarray) -> np.ndarray:
    """(T, 2) (fixed morph, the first solved morph with the same recipe) of a head of
    another convention; recipes ``"0"`` have none."""
    recipe = convention_recipes(morph_names)
    first: dict[str, int] = {}
    for m in solved:
        first.setdefault(recipe.get(int(m), "0"), int(m))
    return np.array([(int(m), first[recipe[int(m)]]) for m in fixed
                     if recipe.get(int(m), "0") != "0" and recipe[int(m)] in first], np.int64).reshape(-1, 2)


def solve_channels(morph_names: list[str]) -> dict[int, tuple[str, ...]]:
    """{morph index: the ARKit curves it stands for} of the morphs a solve may set: each
    ARKit-named morph its name; on a head without ARKit names, each convention morph with a
    recipe the curves that alone turn it on
    (:func:`~capture2face.rig.morph_conventions.convention_channels`)."""
    named = arkit_morphs(morph_names)
    if named:
        return {m: (a,) for m, a in named.items()}
    return convention_channels(morph_names)


def antagonist_unknowns(named: dict[int, str], solved: np.ndarray, offset: int,
                        pairs: tuple[tuple[str, str], ...] = ANTAGONISTS) -> np.ndarray:
    """(P, 2) unknowns (``offset`` plus the position in ``solved``) of the antagonist
    ``pairs`` whose morphs are both solved; ``named``: {morph: ARKit name}
    (two morphs may stand for one name: Rocketbox's inner and outer brow lowering)."""
    column: dict[str, list[int]] = {}
    for k, m in enumerate(solved):
        if int(m) in named:
            column.setdefault(named[int(m)], []).append(offset + k)
    return np.array([(i, j) for a, b in pairs for i in column.get(a, ()) for j in column.get(b, ())],
                    np.int64).reshape(-1, 2)


def rigid_columns(rest: np.ndarray) -> np.ndarray:
    """(3N, 6) d(points)/d(translation, small rotation about the centroid) of ``rest``
    (N, 3): the head motion the pose removal leaves in the landmarks, which no morph
    explains (the default avatar's bones follow it; here it is solved and dropped)."""
    p = rest - rest.mean(0)
    n = len(p)
    cols = np.zeros((n, 3, 6))
    cols[:, :, :3] = np.eye(3)
    for k in range(3):  # d(omega x p)/d(omega_k) = e_k x p
        cols[:, :, 3 + k] = np.cross(np.eye(3)[k], p)
    return cols.reshape(3 * n, 6)


class SteadiedMap:
    """The feature-point network, its motion blended with a similarity's: ``share`` of each
    frame's motion away from the neutral as the network maps it, the rest as the whole
    face's similarity (scale and rotation from the actor's neutral onto the character's)
    carries it. The neutral still lands on the character's neutral exactly.

    Why: the network's local stretch comes from where the landmarks sit on the character,
    which on a third-party head is a cast (:mod:`capture2face.character.landmarks`), not a
    hand-placed correspondence: a landmark row cast a little closer to its neighbours
    shrinks the motion between them (brows rose 0.66 as much as the actor's on an ICT head).
    The similarity keeps motion in proportion to the face's size; the network keeps what
    the character's shape says (a wider eye closes over a longer way).

    Args:
        network: :class:`~capture2face.retarget.rbf.FeatureMap`.
        share: the network's share of the motion (1: the network alone).
    """

    def __init__(self, network, share):
        self.network, self.share = network, np.asarray(share, np.float64)[..., None]
        self.scale, self.rotation, _ = similarity(network.source_neutral, network.target_neutral)

    def __call__(self, source_points: np.ndarray) -> np.ndarray:
        pts = np.asarray(source_points, np.float64)
        mapped = self.network(pts)
        if np.all(self.share >= 1.0):
            return mapped
        rigid = self.network.target_neutral + self.scale * (pts - self.network.source_neutral) @ self.rotation.T
        return self.share * mapped + (1.0 - self.share) * rigid


class CurveShifted:
    """Mapped feature points with the curve-only morphs' motion taken off, by window.

    Args:
        mapped: :class:`~capture2face.retarget.windows.MappedPoints`.
        solve: the :class:`MorphSolve`.
        prior: (F, M) the curves as morph weights.
        ranged: :class:`~capture2face.retarget.ranges.RangeTargets` of the solve, or None
            (every pair as the network maps it).
    """

    def __init__(self, mapped, solve: MorphSolve, prior: np.ndarray, ranged=None):
        self.mapped, self.solve, self.prior, self.ranged = mapped, solve, prior, ranged
        self.windows, self.frames = mapped.windows, mapped.frames

    def read(self, w) -> np.ndarray:
        """(k, N + K, 3) the model's points of the window's frames."""
        pts = self.mapped.read(w)
        shifted = pts
        d = self.solve.fixed_deltas
        if len(d):
            shift = (self.prior[w.start:w.stop, self.solve.fixed].astype(np.float64) @ d.reshape(len(d), -1))
            shifted = pts - shift.reshape(pts.shape)
        out = self.solve.lid_targets(self.solve.points(shifted))
        if self.ranged is None:
            return out
        # The ranged pairs' targets come from the actor's motion (retarget.ranges); the
        # curve-only morphs' part of them is taken off as from the mapped points.
        fixed = self.ranged.components_of(self.solve.points(pts)) - self.ranged.components_of(out)
        actor = np.asarray(self.mapped.source[w.start:w.stop], np.float64)[:, self.mapped.landmarks]
        return self.ranged.apply(out, actor, fixed)

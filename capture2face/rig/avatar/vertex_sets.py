"""Named vertex sets of the default avatar's skin: each eye's lids, each lip, and how much
each vertex goes with the jaw."""

from __future__ import annotations

import numpy as np

from capture2face.rig.avatar.face_mesh import FaceMesh, contour_loop, split_loop
from capture2face.rig.avatar.landmarks import EYE_RINGS, LIP_LOWER_LINES, LIP_UPPER_LINES
from capture2face.rig.avatar.morphs import MorphBuilder
from capture2face.topology import LIP_GAP, LIP_INNER_CORNERS


def vertex_sets(face: FaceMesh, mb: MorphBuilder) -> dict:
    """Vertex sets: contours (with their new edge vertices), lips, lowerness.

    Keys: "eye" (side -> its contour's parts, :func:`_eye_sets`), "lip_loop" (the inner
    lip contour), "lip_upper", "lip_lower" (each lip's vertices), "lip_inner_upper",
    "lip_inner_lower" (the contour's halves), "lowerness" (n_skin,)."""
    sets: dict = {"eye": _eye_sets(face.pos, face.loops)}
    sets.update(_lip_sets(face))
    sets["lowerness"] = _lowerness(mb, sets)
    return sets


def _eye_sets(pos: np.ndarray, loops: list[np.ndarray]) -> dict:
    """side -> dict(upper, lower, corners, ring, upper_full, lower_full, upper_profile,
    lower_profile, below): each eye's contour split into its lids."""
    eye = {}
    for side, (outer, inner, upper_mark) in EYE_RINGS.items():
        loop = contour_loop(loops, upper_mark)
        upper, lower = split_loop(loop, outer, inner, upper_mark)
        corners = np.array([outer, inner])
        # Skin just below the lower lid, raised by a squint.
        below_c = pos[lower].mean(0) + np.array([0.0, -0.9, 0.0])
        below = np.argsort(np.linalg.norm(pos - below_c, axis=1))[:3]
        eye[side] = {"upper": upper, "lower": lower, "corners": corners, "ring": loop,
                     "upper_full": np.concatenate([upper, corners]),
                     "lower_full": np.concatenate([lower, corners]),
                     "upper_profile": _lid_profile(pos, upper, outer, inner),
                     "lower_profile": _lid_profile(pos, lower, outer, inner), "below": below}
    return eye


def _lid_profile(pos: np.ndarray, ids: np.ndarray, outer: int, inner: int) -> np.ndarray:
    """(len(ids),) a half ellipse over the lid's x: 1 midway between its corners, 0 at them."""
    corners = np.array([outer, inner])
    return np.clip(1 - ((pos[ids, 0] - pos[corners, 0].mean()) / (0.5 * abs(pos[outer, 0] - pos[inner, 0]))) ** 2,
                   0, 1) ** 0.5


def _lip_sets(face: FaceMesh) -> dict:
    """The inner lip contour ("lip_loop"), its halves and each lip's vertices."""
    lip_loop = contour_loop(face.loops, LIP_GAP[0])
    inner_upper, inner_lower = split_loop(lip_loop, *LIP_INNER_CORNERS, LIP_GAP[0])
    edge_mid = {tuple(e): face.n_base + i for i, e in enumerate(face.edges.tolist())}

    def with_midpoints(ids):
        ids = {int(i) for i in ids}
        mids = [m for (a, b), m in edge_mid.items() if a in ids and b in ids]
        return np.array(sorted(ids | set(mids)))

    sets = {"lip_loop": lip_loop}
    sets["lip_upper"] = with_midpoints(LIP_UPPER_LINES + list(inner_upper[inner_upper < face.n_base]))
    sets["lip_lower"] = with_midpoints(LIP_LOWER_LINES + list(inner_lower[inner_lower < face.n_base]))
    sets["lip_upper"] = np.union1d(sets["lip_upper"], inner_upper)
    sets["lip_lower"] = np.union1d(sets["lip_lower"], inner_lower)
    sets["lip_inner_upper"], sets["lip_inner_lower"] = inner_upper, inner_lower
    return sets


def _lowerness(mb: MorphBuilder, sets: dict) -> np.ndarray:
    """(n_skin,) how much each skin vertex goes with the jaw."""
    pos, n_skin = mb.pos, mb.n
    # Lowerness: 1 on the lower lip and jaw, 0 on the upper lip and above, harmonic between
    # (the surface path goes around the mouth, so the lips separate cleanly).
    fixed = np.zeros(n_skin, bool)
    val = np.zeros(n_skin)
    top = pos[:, 1] > pos[[129, 358], 1].mean() - 0.3
    bottom = pos[:, 1] < pos[152, 1] + 2.2
    for ids, value in ((top, 0.0), (sets["lip_upper"], 0.0), (bottom, 1.0), (sets["lip_lower"], 1.0)):
        fixed[ids] = True
        val[ids] = value
    return np.clip(mb.harmonic(fixed, val), 0.0, 1.0)

"""Oat's dynamic wrinkle weights: per-triangle area change against the rest pose,
smoothed to vertices over *positions* so that UV seams show no break."""

from __future__ import annotations

import numpy as np

from capture2face.rig.face_rig import FaceRig


def triangle_areas(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3), (T, 3) -> (T,) triangle areas."""
    a, b, c = (positions[triangles[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def corner_angles(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3), (T, 3) -> (T, 3) inner angle (radians) of each triangle at each corner."""
    p = positions[triangles]  # (T, 3, 3)
    e1 = np.roll(p, -1, axis=1) - p  # corner -> next corner
    e2 = np.roll(p, -2, axis=1) - p  # corner -> previous corner
    cross = np.linalg.norm(np.cross(e1, e2), axis=2)
    return np.arctan2(cross, np.einsum("tcd,tcd->tc", e1, e2))


def triangle_wrinkle_weights(rest: np.ndarray, positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Per triangle ``clamp((A_rest - A_now) / A_rest, -1, 1)``: + compressed, - stretched.

    Returns (T,) float64; 0 for triangles without rest area.
    """
    a_rest = triangle_areas(rest, triangles)
    a_now = triangle_areas(positions, triangles)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(a_rest > 0, (a_rest - a_now) / a_rest, 0.0)
    return np.clip(w, -1.0, 1.0)


def dynamic_wrinkle_weights(rig: FaceRig, positions: np.ndarray) -> np.ndarray:
    """Smoothed per-vertex area-change weights (Oat 2007).

    Each vertex takes the average of the weights of the triangles around its *position*
    (``rig.position_ids``: copies split at UV seams count as one), weighted by each
    triangle's inner angle at that corner.

    Args:
        rig: the rig (rest ``vertices``, ``triangles``, ``position_ids``).
        positions: (V, 3) deformed positions, head coordinates.
    Returns:
        (V,) float32 in [-1, 1]: + compress, - stretch.
    """
    positions = np.asarray(positions, np.float64)
    tris = rig.triangles
    w_tri = triangle_wrinkle_weights(rig.vertices.astype(np.float64), positions, tris)
    angle = corner_angles(positions, tris)  # (T, 3)
    ids = rig.position_ids[tris].ravel()
    n_ids = int(rig.position_ids.max()) + 1
    num = np.bincount(ids, weights=(angle * w_tri[:, None]).ravel(), minlength=n_ids)
    den = np.bincount(ids, weights=angle.ravel(), minlength=n_ids)
    with np.errstate(divide="ignore", invalid="ignore"):
        per_position = np.where(den > 0, num / den, 0.0)
    return per_position[rig.position_ids].astype(np.float32)

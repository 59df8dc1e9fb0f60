"""One mesh's vertices welded by position (UV seams closed): its smooth normals and the
normal deltas its morphs imply, without shading seams."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.rig.mesh_ops import welded_normals


@dataclass(frozen=True)
class Welding:
    """``ids`` (n,) weld id of each vertex, ``first`` (W,) the first vertex of each id,
    ``tris`` (T, 3) the triangles over weld ids, ``stand_in`` (n,) the first vertex of
    each vertex's id (what :func:`~capture2face.rig.mesh_ops.welded_normals` takes)."""

    ids: np.ndarray
    first: np.ndarray
    tris: np.ndarray
    stand_in: np.ndarray


def weld_ids(vertices: np.ndarray) -> np.ndarray:
    """(n,) vertices at the same position (to 1e-5 of their unit) share an id."""
    key = np.round(vertices.astype(np.float64) * 1e5).astype(np.int64)
    _, ids = np.unique(key, axis=0, return_inverse=True)
    return ids.reshape(-1)


def welding(pos: np.ndarray, tris: np.ndarray) -> Welding:
    """The welding of positions ``pos`` (n, 3) with triangles ``tris`` (T, 3)."""
    ids = weld_ids(pos)
    first = np.unique(ids, return_index=True)[1]
    return Welding(ids=ids, first=first, tris=ids[tris], stand_in=first[ids])


def smooth_normals(pos: np.ndarray, tris: np.ndarray, weld: Welding) -> np.ndarray:
    """(n, 3) smooth unit normals of positions ``pos`` (n, 3), welded (no seam at UV splits)."""
    return welded_normals(pos, tris, weld.stand_in)


def morph_normal_deltas(given: np.ndarray, deltas: np.ndarray, pos: np.ndarray, tris: np.ndarray,
                        weld: Welding) -> np.ndarray:
    """(K, n, 3) normal deltas of one mesh's K morphs in scene space: the file's NORMAL
    deltas (``given``, NaN where it has none), else derived from the position deltas
    ``deltas`` (K, n, 3) at rest positions ``pos`` (n, 3): the welded smooth normals of the
    morphed shape minus those of the rest shape, computed the same way, so they cancel
    wherever the morph leaves a vertex's triangles alone; the delta is exactly 0 there."""
    out = np.array(given, np.float64)
    missing = ~np.isfinite(out).all(axis=(1, 2))
    if not missing.any():
        return out
    ids, wtris = weld.ids, weld.tris
    n_weld = len(weld.first)
    rest = smooth_normals(pos, tris, weld)
    for k in np.flatnonzero(missing):
        moved = np.zeros(n_weld, bool)
        moved[ids[np.abs(deltas[k]).max(axis=1) > 0]] = True
        touched = np.zeros(n_weld, bool)  # every vertex of a triangle that moved
        touched[wtris[moved[wtris].any(axis=1)]] = True
        derived = np.zeros((len(ids), 3))
        if touched.any():
            morphed = smooth_normals(pos + deltas[k], tris, weld)
            near = touched[ids]
            derived[near] = morphed[near] - rest[near]
        out[k] = np.where(np.isfinite(out[k]), out[k], derived)
    return out

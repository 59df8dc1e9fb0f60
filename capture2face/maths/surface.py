"""Closest points on a triangle mesh, as barycentric coordinates."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

_CHUNK = 65536  # query points per pass: the (n, candidates, 3) temporaries stay small


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(..., 3) barycentric weights of the point of each triangle (a, b, c) nearest ``p``
    (all (..., 3), 3D): Ericson's regions (vertex, edge, face), vectorized."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("...c,...c->...", ab, ap), np.einsum("...c,...c->...", ac, ap)
    bp, cp = p - b, p - c
    d3, d4 = np.einsum("...c,...c->...", ab, bp), np.einsum("...c,...c->...", ac, bp)
    d5, d6 = np.einsum("...c,...c->...", ab, cp), np.einsum("...c,...c->...", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    tiny = 1e-30
    # Face region by default; the edge and vertex regions override it (checked last wins).
    den = np.maximum(va + vb + vc, tiny)
    v, w = vb / den, vc / den
    out = np.stack([1.0 - v - w, v, w], -1)
    t_bc = np.clip((d4 - d3) / np.maximum((d4 - d3) + (d5 - d6), tiny), 0, 1)
    edge_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    out[edge_bc] = np.stack([np.zeros_like(t_bc), 1 - t_bc, t_bc], -1)[edge_bc]
    t_ac = np.clip(d2 / np.maximum(d2 - d6, tiny), 0, 1)
    edge_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    out[edge_ac] = np.stack([1 - t_ac, np.zeros_like(t_ac), t_ac], -1)[edge_ac]
    t_ab = np.clip(d1 / np.maximum(d1 - d3, tiny), 0, 1)
    edge_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    out[edge_ab] = np.stack([1 - t_ab, t_ab, np.zeros_like(t_ab)], -1)[edge_ab]
    for corner, region in enumerate(((d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (d6 >= 0) & (d5 <= d6))):
        out[region] = np.eye(3)[corner]
    return out


def closest_points(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                   k: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The point of the mesh nearest each of ``points`` (N, 3), searched among the
    triangles around its ``k`` nearest mesh vertices (exact but for points near a concave
    fold of the mesh, where the nearest point may lie a ring further: fitted faces do not
    depend on it).

    Returns:
        triangle index (N,), barycentric weights (N, 3), distance (N,).
    """
    vertices = np.asarray(vertices, np.float32)  # float32 halves the time; cm-sized faces need no more
    used = np.unique(triangles)
    # Each vertex's triangles, padded with its first one.
    order = np.argsort(triangles.ravel(), kind="stable")
    owner = triangles.ravel()[order]
    starts = np.searchsorted(owner, np.arange(len(vertices)))
    counts = np.bincount(owner, minlength=len(vertices))
    ring = int(counts.max())
    slot = starts[:, None] + np.minimum(np.arange(ring)[None], np.maximum(counts - 1, 0)[:, None])
    around = (order[np.minimum(slot, len(order) - 1)] // 3).reshape(len(vertices), ring)
    tree = cKDTree(vertices[used])
    tri = np.zeros(len(points), np.int64)
    bary = np.zeros((len(points), 3))
    dist = np.zeros(len(points))
    for s in range(0, len(points), _CHUNK):
        p = np.asarray(points[s:s + _CHUNK], np.float32)
        _, near = tree.query(p, k=k)
        cand = around[used[near.reshape(len(p), -1)]].reshape(len(p), -1)  # (n, k * ring)
        corners = vertices[triangles[cand]]  # (n, C, 3, 3)
        bc = closest_on_triangles(p[:, None], corners[..., 0, :], corners[..., 1, :], corners[..., 2, :])
        q = np.einsum("ncj,ncjd->ncd", bc, corners)
        d = np.linalg.norm(q - p[:, None], axis=-1)
        best = np.argmin(d, 1)
        rows = np.arange(len(p))
        tri[s:s + len(p)], bary[s:s + len(p)], dist[s:s + len(p)] = cand[rows, best], bc[rows, best], d[rows, best]
    return tri, bary, dist

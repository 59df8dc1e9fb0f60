"""Mesh operations the avatar builder needs, vectorized over NumPy arrays.

Subdivision that keeps the original vertices first, vertex normals and UV tangents,
boundary loops, graph geodesics and (bi)harmonic extension of prescribed displacements.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def unique_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) -> (E, 2) sorted unique edges and (T, 3) edge index of each triangle side
    (side k joins corners k and k+1)."""
    sides = np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=-1).reshape(-1, 2)
    edges, inverse = np.unique(np.sort(sides, axis=1), axis=0, return_inverse=True)
    return edges, inverse.reshape(-1, 3)


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3) area-weighted unit vertex normals (a vertex in no triangle gets +z).

    Works on batches too: vertices (..., V, 3) -> (..., V, 3).
    """
    v = np.asarray(vertices, np.float64)
    a, b, c = v[..., triangles[:, 0], :], v[..., triangles[:, 1], :], v[..., triangles[:, 2], :]
    face = np.cross(b - a, c - a)  # length = 2 * area: area weighting for free
    inc = _incidence(triangles, v.shape[-2])  # (V, T)
    if v.ndim == 2:
        n = inc @ face
    else:
        lead = v.shape[:-2]
        flat = np.moveaxis(face.reshape(-1, len(triangles), 3), 1, 0).reshape(len(triangles), -1)
        n = np.moveaxis((inc @ flat).reshape(v.shape[-2], -1, 3), 0, 1).reshape(*lead, v.shape[-2], 3)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    out = np.where(length > 1e-12, n / np.maximum(length, 1e-12), np.array([0.0, 0.0, 1.0]))
    return out


def welded_normals(positions: np.ndarray, triangles: np.ndarray, position_ids: np.ndarray) -> np.ndarray:
    """(..., V, 3) vertex normals computed over positions, not vertices: copies of one
    position (a UV seam) share one normal, so no shading seam shows. ``position_ids`` (V,):
    the vertex index that stands for each vertex's position."""
    return vertex_normals(positions, position_ids[triangles])[..., position_ids, :]


def _incidence(triangles: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    rows = triangles.ravel()
    cols = np.repeat(np.arange(len(triangles)), 3)
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, len(triangles)))


def midpoint_subdivide(vertices: np.ndarray, triangles: np.ndarray,
                       normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One 1-to-4 split. Original vertices keep their indices (0..V-1); edge vertex e is
    V + e. New vertices sit on a cubic Hermite curve between the edge's ends (tangents
    from the end normals, as in PN triangles), so the surface rounds out instead of
    staying faceted.

    Returns (vertices (V+E, 3), triangles (4T, 3), edges (E, 2)).
    """
    edges, tri_edge = unique_edges(triangles)
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    na, nb = normals[edges[:, 0]], normals[edges[:, 1]]
    e = b - a
    bulge = ((e * nb).sum(1, keepdims=True) * nb - (e * na).sum(1, keepdims=True) * na) / 8.0
    mids = 0.5 * (a + b) + bulge
    m = len(vertices) + tri_edge  # (T, 3): midpoint of side k (corner k -> k+1)
    t0, t1, t2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    m01, m12, m20 = m[:, 0], m[:, 1], m[:, 2]
    new = np.concatenate([
        np.stack([t0, m01, m20], 1), np.stack([m01, t1, m12], 1),
        np.stack([m20, m12, t2], 1), np.stack([m01, m12, m20], 1),
    ])
    return np.vstack([vertices, mids]), new.astype(np.int32), edges


def uv_tangents(vertices: np.ndarray, normals: np.ndarray, uvs: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 4) unit tangents along +u with handedness w so that the bitangent
    ``w * cross(n, t)`` points along -v (up in the image: OpenGL-style normal maps)."""
    p = vertices[triangles]  # (T, 3, 3)
    t = uvs[triangles]  # (T, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    d1, d2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    r = np.where(np.abs(det) > 1e-12, 1.0 / np.where(det == 0, 1, det), 0.0)[:, None]
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r
    dpdv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r
    inc = _incidence(triangles, len(vertices))
    tu, tv = inc @ dpdu, inc @ dpdv
    # Gram-Schmidt against the normal; fall back to any perpendicular where UVs degenerate.
    tu = tu - (tu * normals).sum(1, keepdims=True) * normals
    length = np.linalg.norm(tu, axis=1, keepdims=True)
    fallback = np.cross(normals, np.array([0.0, 1.0, 0.0]))
    fallback /= np.maximum(np.linalg.norm(fallback, axis=1, keepdims=True), 1e-9)
    tu = np.where(length > 1e-9, tu / np.maximum(length, 1e-12), fallback)
    w = np.where((np.cross(normals, tu) * -tv).sum(1) < 0, -1.0, 1.0)
    return np.concatenate([tu, w[:, None]], axis=1)


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """Ordered vertex loops of the mesh's boundary edges (each edge used by one triangle)."""
    sides = np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=-1).reshape(-1, 2)
    key = np.sort(sides, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    border = sides[counts[inverse.ravel()] == 1]
    nxt = dict(zip(border[:, 0].tolist(), border[:, 1].tolist()))
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, cur = [], start
        while cur not in seen:
            seen.add(cur)
            loop.append(cur)
            cur = nxt[cur]
        loops.append(np.array(loop, np.int64))
    return loops


def edge_graph(vertices: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """Symmetric sparse (V, V) matrix of edge lengths."""
    edges, _ = unique_edges(triangles)
    length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    n = len(vertices)
    g = sp.coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n))
    return (g + g.T).tocsr()


def uniform_laplacian(n_vertices: int, triangles: np.ndarray) -> sp.csr_matrix:
    """(V, V) graph Laplacian D - A of the triangle edges."""
    edges, _ = unique_edges(triangles)
    a = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_vertices, n_vertices))
    a = (a + a.T).tocsr()
    return (sp.diags(np.asarray(a.sum(1)).ravel()) - a).tocsr()


def smooth_extension(laplacian: sp.csr_matrix, fixed: np.ndarray, values: np.ndarray, order: int = 2) -> np.ndarray:
    """Extend ``values`` given at ``fixed`` vertices to all others by minimizing the
    (bi)harmonic energy: ``order=1`` solves L x = 0, ``order=2`` L^T L x = 0 on the free
    vertices. Vertices in no component with a fixed vertex get 0.

    Args:
        laplacian: (V, V) from :func:`uniform_laplacian`.
        fixed: (V,) bool.
        values: (V, C) values (only rows where ``fixed`` are read).
    Returns:
        (V, C) float64.
    """
    op = laplacian if order == 1 else (laplacian.T @ laplacian).tocsr()
    free = ~fixed
    out = np.where(fixed[:, None], values, 0.0).astype(np.float64)
    if free.any():
        a = op[free][:, free].tocsc()
        rhs = -(op[free][:, fixed] @ out[fixed])
        # A tiny ridge keeps components without a fixed vertex solvable (they go to 0).
        a = a + sp.identity(a.shape[0], format="csc") * 1e-9
        out[free] = spla.splu(a).solve(rhs)
    return out

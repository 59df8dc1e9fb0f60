"""The default avatar's skin: MediaPipe's canonical face mesh with its lips closed, reshaped
for a variant, its eyes and mouth opened, subdivided once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.rig import canonical, mesh_ops
from capture2face.rig.avatar.landmarks import LIP_LOWER_LINES, LIP_UPPER_LINES
from capture2face.rig.avatar.morphs import mirror_map
from capture2face.rig.avatar.variants import variant_shape
from capture2face.topology import EYE_RIGHT, LIP_INNER_LOWER, LIP_INNER_UPPER, LIPS_INNER

# Inner-lip vertex pairs (upper, lower) that meet when the lips close.
LIP_PAIRS = list(zip(LIP_INNER_UPPER, LIP_INNER_LOWER))


def close_lips(v: np.ndarray) -> np.ndarray:
    """(N >= 468, 3) points indexed like MediaPipe's landmarks, with the lips closed.

    The canonical face rests with its lips ~0.5 cm apart; a neutral face has them
    touching. Move the inner lip lines onto their common midline and let the rest of
    each lip follow, fading out over 1 cm."""
    v = v.copy()
    up, lo = np.array(LIP_PAIRS).T
    half_gap = 0.5 * (v[up] - v[lo])  # (9, 3)
    order = np.argsort(v[up, 0])
    xs = v[up[order], 0]
    for ids, sign, line in ((LIP_UPPER_LINES, -1.0, up), (LIP_LOWER_LINES, 1.0, lo)):
        ids = np.array(ids)
        inner_y = np.interp(v[ids, 0], np.sort(v[line, 0]), v[line[np.argsort(v[line, 0])], 1])
        fade = np.clip(1.0 - np.abs(v[ids, 1] - inner_y) / 1.0, 0.0, 1.0) ** 2
        d = np.stack([np.interp(v[ids, 0], xs, half_gap[order, c]) for c in range(3)], 1)
        v[ids] += sign * d * fade[:, None]
    v[up] = v[lo] = 0.5 * (v[up] + v[lo])  # the inner lines meet exactly
    return v


def remove_hole_fills(triangles: np.ndarray, rings: list[list[int]]) -> np.ndarray:
    """Drop triangles whose three corners lie on one eye or lip contour (the canonical
    mesh closes the eyes and the mouth; the avatar needs them open)."""
    drop = np.zeros(len(triangles), bool)
    for ring in rings:
        drop |= np.isin(triangles, ring).all(axis=1)
    return triangles[~drop]


def contour_loop(loops: list[np.ndarray], member: int) -> np.ndarray:
    for loop in loops:
        if member in loop:
            return loop
    raise RuntimeError(f"no boundary loop through vertex {member}")


def split_loop(loop: np.ndarray, a: int, b: int, through: int) -> tuple[np.ndarray, np.ndarray]:
    """Split a closed loop at vertices a and b; return (part containing ``through``,
    the other part), both without the corners."""
    loop = list(loop)
    ia = loop.index(a)
    loop = loop[ia:] + loop[:ia]
    ib = loop.index(b)
    first, second = np.array(loop[1:ib]), np.array(loop[ib + 1:])
    return (first, second) if through in first else (second, first)


@dataclass
class FaceMesh:
    """The face's skin: the canonical mesh with its eyes and mouth opened, subdivided once
    (n_skin vertices: the canonical ones keep their ids, edge midpoints follow)."""

    canonical_uvs: np.ndarray  # (468, 2) the canonical mesh's UVs (the feature layout's space)
    mirror: np.ndarray  # (468,) each canonical landmark's mirror image
    n_base: int  # canonical vertices; the midpoint of edges[e] is vertex n_base + e
    pos: np.ndarray  # (n_skin, 3)
    tris: np.ndarray  # (T, 3)
    edges: np.ndarray  # (E, 2) the edges that were split
    uvs: np.ndarray  # (n_skin, 2)
    normals: np.ndarray  # (n_skin, 3)
    loops: list  # the skin's boundary loops: eyes, mouth, outer edge


def build_face_mesh(variant: str) -> FaceMesh:
    """The face's skin of ``variant``: the canonical mesh with its lips closed, reshaped,
    its eyes and mouth opened, subdivided once."""
    mesh = canonical.load_canonical_mesh()
    base = variant_shape(close_lips(mesh.vertices.astype(np.float64)), variant)
    mirror = mirror_map(mesh.vertices.astype(np.float64))

    # Open the eyes and the mouth, then subdivide once (original vertices keep their ids).
    # remove_hole_fills reads each contour as a set of vertices: the order does not matter.
    eye_contours = [list(EYE_RIGHT)]
    eye_contours.append(list(mirror[eye_contours[0]]))
    lip_contour = list(LIPS_INNER)
    tris0 = remove_hole_fills(mesh.triangles, eye_contours + [lip_contour])
    n0 = mesh_ops.vertex_normals(base, tris0)
    pos, tris, edges = mesh_ops.midpoint_subdivide(base, tris0, n0)
    uvs = np.vstack([mesh.uvs, 0.5 * (mesh.uvs[edges[:, 0]] + mesh.uvs[edges[:, 1]])]).astype(np.float64)
    normals = mesh_ops.vertex_normals(pos, tris)
    return FaceMesh(canonical_uvs=mesh.uvs, mirror=mirror, n_base=len(base), pos=pos, tris=tris, edges=edges,
                     uvs=uvs, normals=normals, loops=mesh_ops.boundary_loops(tris))

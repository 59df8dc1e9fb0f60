"""The default avatar's vertex layout: the skin first, then the eyeballs, the mouth interior,
the teeth and tongue, the head shell and the ears, each placed after the last (the parts'
geometry is :mod:`capture2face.rig.avatar.parts`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from capture2face.rig import features, maps
from capture2face.rig.avatar.parts import (
    FACE_BLEND_RINGS,
    HEAD_RINGS,
    ear,
    eyeball,
    head_shell,
    mouth_interior,
    teeth_and_tongue,
)
from capture2face.topology import IOD_PAIR, IRIS_CENTRES, N_LANDMARKS, N_MESH


@dataclass
class Parts:
    """The avatar's vertices part after part: positions, UVs, triangles (numbered over
    the whole avatar as they are added) and a material per vertex."""

    positions: list = field(default_factory=list)
    uvs: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    material: list = field(default_factory=list)
    size: int = 0  # vertices so far

    def add(self, verts: np.ndarray, uvs: np.ndarray, tris: np.ndarray, material: int) -> int:
        """Append a part, its ``tris`` numbered over its own vertices; returns its first
        vertex."""
        start = self.size
        self.positions.append(verts)
        self.uvs.append(uvs)
        self.triangles.append(tris + start)
        self.material.append(np.full(len(verts), material, np.uint8))
        self.size += len(verts)
        return start

    def stack(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(positions (V, 3), uvs (V, 2), triangles (T, 3) int32, material (V,) uint8)."""
        return (np.vstack(self.positions), np.vstack(self.uvs), np.vstack(self.triangles).astype(np.int32),
                np.concatenate(self.material))


@dataclass
class Eyes:
    """The eyeballs' place among the avatar's vertices and what the rig keeps of them."""

    landmark_vertices: np.ndarray  # (478,) the vertex each tracker landmark sits on
    iris_theta: dict  # side -> the iris rim's polar angle on the eyeball
    centres: list  # [(3,), (3,)] right and left rotation centres
    side: np.ndarray  # (n eye vertices,) int8 0 right, 1 left
    start: int


@dataclass
class Mouth:
    """The mouth interior's place among the avatar's vertices and where it hangs from."""

    source: np.ndarray  # (N,) contour vertex each mouth vertex copies from (-1 = cap)
    depth: np.ndarray  # (N,) in [0, 1]
    src: np.ndarray  # (N,) source with the cap's -1 as 0
    last_ring: np.ndarray  # contour vertices of the ring before the cap
    start: int
    end: int


@dataclass
class Teeth:
    """The teeth and tongue's place among the avatar's vertices."""

    verts: np.ndarray  # (K, 3)
    part: np.ndarray  # (K,) 0 upper teeth, 1 lower teeth, 2 tongue
    start: int
    end: int


@dataclass
class Head:
    """The head shell's place among the avatar's vertices and how it meets the face."""

    verts: np.ndarray  # (H, 3) the head shell
    ring: np.ndarray  # (H,) ring index
    col: np.ndarray  # (H,) column index, n_edge = the copy of column 0
    edge: np.ndarray  # (n_edge,) the face's outer edge loop
    src: np.ndarray  # (H,) the edge vertex each shell vertex follows
    follow: np.ndarray  # (H, 1) how much of that edge vertex's skinning and morphs it takes
    start: int
    end: int

    @property
    def n_edge(self) -> int:
        return len(self.edge)


def add_eyes(parts: Parts, pos: np.ndarray, eye_sets: dict) -> Eyes:
    """The eyeballs (material 1), right then left, behind the skin's eye openings; the
    iris landmarks (468-477) sit on their vertices."""
    landmark_vertices = np.full(N_LANDMARKS, -1, np.int32)
    landmark_vertices[:N_MESH] = np.arange(N_MESH)
    start = parts.size
    iris_theta = {}
    eye_centres, eye_side = [], []
    for k, (side, first_landmark) in enumerate(zip(("R", "L"), IRIS_CENTRES)):
        ring = eye_sets[side]["ring"]
        ev, euv, etri, iris, iris_theta[side], centre = eyeball(pos[ring], side)
        eye_centres.append(centre)
        eye_side.append(np.full(len(ev), k, np.int8))
        offset = parts.add(ev, euv, etri, 1)
        landmark_vertices[first_landmark:first_landmark + 5] = offset + iris
    return Eyes(landmark_vertices, iris_theta, eye_centres, np.concatenate(eye_side), start)


def add_mouth_interior(parts: Parts, pos: np.ndarray, sets: dict) -> Mouth:
    """The mouth interior (material 2) hanging back from the inner lip contour."""
    lip_loop, inner_upper, inner_lower = sets["lip_loop"], sets["lip_inner_upper"], sets["lip_inner_lower"]
    upperness = np.where(np.isin(lip_loop, inner_upper), 1.0, np.where(np.isin(lip_loop, inner_lower), -1.0, 0.0))
    mv, msource, mdepth, mtri = mouth_interior(lip_loop, pos, upperness)
    # Mouth UVs: angle around the mouth -> angle in the disc, depth -> radius.
    angle = np.arctan2(*(mv[:, :2] - mv[:-1, :2].mean(0)).T[::-1])
    radius = maps.MOUTH_TEXTURE_RADIUS * (0.25 + 0.75 * mdepth)
    mouth_uv = np.array(maps.MOUTH_TEXTURE_CENTRE) + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
    # Both windings: an opening jaw turns some walls away from the camera, and back faces
    # are culled (FaceRig.double_sided False); the bag is dark either way.
    start = parts.add(mv, mouth_uv, np.vstack([mtri, mtri[:, ::-1]]), 2)
    # The cap has no contour vertex of its own: it takes the mean of the last ring's.
    src = np.where(msource >= 0, msource, 0)
    last_ring = msource[-1 - len(lip_loop):-1]
    return Mouth(msource, mdepth, src, last_ring, start, start + len(mv))


def add_teeth(parts: Parts, pos: np.ndarray, lip_loop: np.ndarray) -> Teeth:
    """Teeth and tongue (material 3) behind the inner lip contour."""
    # Teeth and tongue: the upper teeth ride the head, the lower ones and the tongue the jaw.
    tv, tuv, ttri, tpart = teeth_and_tongue(pos[lip_loop])
    start = parts.add(tv, tuv, ttri, 3)
    return Teeth(tv, tpart, start, start + len(tv))


def add_head_shell(parts: Parts, pos: np.ndarray, loops: list[np.ndarray]) -> Head:
    """The head beyond the face (material 4) without the ears."""
    # The head beyond the face (material 4): scalp, back of the head and neck grown from
    # the face's outer edge (its first ring shares the edge's positions), then the ears.
    edge = max(loops, key=len)
    hv, hring, hcol, htri = head_shell(pos[edge], pos[152])
    n_edge = len(edge)
    huv = np.stack([maps.HEAD_U[0] + (maps.HEAD_U[1] - maps.HEAD_U[0]) * hcol / n_edge,
                    maps.HEAD_V[0] + (maps.HEAD_V[1] - maps.HEAD_V[0]) * hring / HEAD_RINGS], 1)
    start = parts.add(hv, huv, htri, 4)
    # The head's first rings take the face edge's skinning and morphs, fading to the head bone.
    head_src = edge[hcol % n_edge]
    follow = (1.0 - features.smoothstep(hring / FACE_BLEND_RINGS))[:, None]
    return Head(hv, hring, hcol, edge, head_src, follow, start, start + len(hv))


def add_ears(parts: Parts, pos: np.ndarray, head: Head) -> int:
    """The ears (material 4) on the head shell's sides, right then left; returns the
    first ear vertex."""
    start = parts.size
    hv, edge = head.verts, head.edge
    ear_y = 0.5 * (pos[list(IOD_PAIR), 1].mean() + pos[2, 1])  # between eye and nose base levels
    ear_z = float(pos[edge, 2].min()) - 2.2
    for side, (u0, u1) in ((-1.0, maps.EAR_U["R"]), (1.0, maps.EAR_U["L"])):
        near = (np.abs(hv[:, 1] - ear_y) < 1.0) & (np.abs(hv[:, 2] - ear_z) < 1.0) & (hv[:, 0] * side > 0)
        x = float(np.abs(hv[near, 0]).max()) if near.any() else float(np.abs(pos[edge, 0]).max())
        ev, ecoord, efront, etri = ear(np.array([side * (x + 0.35), ear_y, ear_z]), side, 6.0, 3.3)
        r_uv = np.where(efront, 0.5 * ecoord[:, 0], 1.0 - 0.5 * ecoord[:, 0]) * 0.5 * (maps.EAR_V[1] - maps.EAR_V[0])
        a = 2 * np.pi * ecoord[:, 1]
        c = np.array([0.5 * (u0 + u1), 0.5 * (maps.EAR_V[0] + maps.EAR_V[1])])
        parts.add(ev, c + r_uv[:, None] * np.stack([np.cos(a), np.sin(a)], 1), etri, 4)
    return start


def shared_position_ids(V: int, head: Head) -> np.ndarray:
    """(V,) int32 :attr:`FaceRig.position_ids`."""
    # Vertices that share a position: the head's first ring and the face's edge, and each
    # ring's closing copy of its first vertex (UV seams without a shading seam).
    position_ids = np.arange(V, dtype=np.int32)
    n_edge, hring, hcol = head.n_edge, head.ring, head.col
    head_ids = head.start + np.arange(len(head.verts))
    position_ids[head_ids[hcol == n_edge]] = head_ids[hcol == 0]
    position_ids[head_ids[hring == 0]] = head.edge[hcol[hring == 0] % n_edge]
    return position_ids


def f32(a) -> np.ndarray:
    """``a`` as a contiguous float32 array (what FaceRig stores)."""
    return np.ascontiguousarray(a, dtype=np.float32)

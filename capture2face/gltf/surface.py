"""The drawn surface: every mesh node's mesh (:mod:`.meshes`) moved to scene space (its
node's world transform, or its skin's bind pose) and scaled to cm, normals and tangents
computed where the file has none, all merged into one vertex array."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.gltf.container import GlbReader
from capture2face.gltf.mapping import Mapping
from capture2face.gltf.meshes import read_mesh
from capture2face.gltf.skins import Skeleton
from capture2face.gltf.welding import morph_normal_deltas, smooth_normals, welding
from capture2face.rig.mesh_ops import uv_tangents


@dataclass(frozen=True)
class Part:
    """One drawn mesh in scene space (n vertices from row ``offset``, K morph targets).

    positions (n, 3) cm, normals (n, 3), tangents (n, 4), uvs (n, 2), triangles (T, 3)
    (rows of the whole surface), material (n,), gltf_material (n,), bones / weights (n, J)
    (skin as FaceRig bones, None unskinned), joints (n, J) the file's own JOINTS, position_ids
    (n,) and regions (n, R) (our own export's), morph_positions (K, n, 3) cm, morph_normals
    (K, n, 3), morph_names (K,), its largest primitive's material and its triangle count.
    """

    positions: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    uvs: np.ndarray
    triangles: np.ndarray
    material: np.ndarray
    gltf_material: np.ndarray
    bones: np.ndarray | None
    weights: np.ndarray | None
    joints: np.ndarray | None
    position_ids: np.ndarray | None
    regions: np.ndarray | None
    morph_positions: np.ndarray
    morph_normals: np.ndarray
    morph_names: list[str]
    largest_material: int | None
    tri_count: int
    offset: int

    @property
    def rows(self) -> slice:
        """This mesh's rows in the surface's vertex arrays."""
        return slice(self.offset, self.offset + len(self.positions))


@dataclass(frozen=True)
class Surface:
    """Every drawn mesh, one vertex array (V vertices): vertices (V, 3) float32 cm,
    normals (V, 3), tangents (V, 4), uvs (V, 2) float64, triangles (T, 3), material (V,),
    gltf_material (V,); position_ids, regions, joints and weights as the file has them
    where it has one mesh (our own export), else None; the material of the largest mesh's
    largest primitive."""

    parts: list[Part]
    n_vertices: int
    vertices: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    uvs: np.ndarray
    triangles: np.ndarray
    material: np.ndarray
    gltf_material: np.ndarray
    position_ids: np.ndarray | None
    regions: np.ndarray | None
    joints: np.ndarray | None
    weights: np.ndarray | None
    largest_material: int | None


def _tangents(tan: np.ndarray | None, lin: np.ndarray, pos: np.ndarray, normals: np.ndarray, uvs: np.ndarray,
              tris: np.ndarray) -> np.ndarray:
    """(n, 4) scene-space tangents: the file's (through ``lin`` (3, 3)), else from the UVs."""
    if tan is not None and np.isfinite(tan).all():
        t = tan[:, :3] @ lin.T
        return np.concatenate([t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12),
                               np.where(tan[:, 3:] < 0, -1.0, 1.0) * np.sign(np.linalg.det(lin))], 1)
    return uv_tangents(pos, normals, uvs.astype(np.float64), tris)


def _part(r: GlbReader, ni: int, skeleton: Skeleton, mapping: Mapping, scale: float, offset: int) -> Part:
    """Mesh node ``ni``'s mesh in scene space, its rows from ``offset``."""
    g = r.gltf
    m = read_mesh(r, g["meshes"][g["nodes"][ni]["mesh"]], mapping)
    to_scene = skeleton.node_to_scene[ni]
    lin = to_scene[:3, :3]
    normal_rows = np.linalg.inv(lin)  # normals as rows: (inv(lin)^T n)^T = n^T inv(lin)
    pos = m.positions @ lin.T + to_scene[:3, 3]
    weld = welding(pos, m.triangles)
    if m.normals is not None and np.isfinite(m.normals).all():
        normals = m.normals @ normal_rows
    else:
        computed = smooth_normals(pos, m.triangles, weld)
        normals = computed if m.normals is None else np.where(np.isfinite(m.normals), m.normals @ normal_rows,
                                                              computed)
    # A file's NORMAL deltas go through the same transform and the same normalising scale.
    normal_scale = 1.0 / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    normals = normals * normal_scale
    uvs = m.uvs if m.uvs is not None else np.zeros((len(pos), 2))
    tangents = _tangents(m.tangents, lin, pos, normals, uvs, m.triangles)
    bones = None
    if m.joints is not None and ni in skeleton.node_joint_map:
        remap = skeleton.node_joint_map[ni]
        bones = skeleton.joint_to_bone[remap[np.clip(m.joints, 0, len(remap) - 1)]]
    mnrm = morph_normal_deltas(m.morph_normals @ normal_rows * normal_scale, m.morph_positions @ lin.T, pos,
                               m.triangles, weld)
    return Part(positions=pos * scale, normals=normals, tangents=tangents, uvs=uvs, triangles=m.triangles + offset,
                material=m.material, gltf_material=m.gltf_material, bones=bones, weights=m.weights,
                joints=m.joints,  # the file's own JOINTS_0 (our export's eye joints are no bones)
                position_ids=m.position_ids, regions=m.regions, morph_positions=m.morph_positions @ lin.T * scale,
                morph_normals=mnrm, morph_names=m.target_names, largest_material=m.largest_material,
                tri_count=m.tri_count, offset=offset)


def scene_surface(r: GlbReader, picked: list[int], skeleton: Skeleton, mapping: Mapping, scale: float) -> Surface:
    """Every drawn mesh (nodes ``picked``) in scene space, one vertex array: positions
    (cm), normals, tangents, UVs, triangles, material codes, skin joints (as bones) and
    weights, morph deltas with their names per mesh."""
    parts = []
    offset = 0
    for ni in picked:
        parts.append(_part(r, ni, skeleton, mapping, scale, offset))
        offset += len(parts[-1].positions)
    # Tangents where UVs are degenerate and the normal is parallel to the fallback axis:
    # any perpendicular will do, take one from the x axis.
    normals = np.concatenate([p.normals for p in parts])
    tangents = np.concatenate([p.tangents for p in parts])
    bad = ~(np.linalg.norm(tangents[:, :3], axis=1) > 0.5)
    if bad.any():
        alt = np.cross(normals[bad], np.array([1.0, 0.0, 0.0]))
        tangents[bad, :3] = alt / np.maximum(np.linalg.norm(alt, axis=1, keepdims=True), 1e-12)
        tangents[bad, 3] = 1.0
    single = len(parts) == 1
    return Surface(
        parts=parts, n_vertices=offset,
        vertices=np.concatenate([p.positions for p in parts]).astype(np.float32),
        normals=normals, tangents=tangents,
        uvs=np.concatenate([p.uvs for p in parts]).astype(np.float64),
        triangles=np.concatenate([p.triangles for p in parts]),
        material=np.concatenate([p.material for p in parts]),
        gltf_material=np.concatenate([p.gltf_material for p in parts]),
        # What only our own (single-mesh) export has: vertex ids, regions, raw skin indices.
        position_ids=parts[0].position_ids if single else None,
        regions=parts[0].regions if single else None,
        joints=parts[0].joints if single else None,
        weights=parts[0].weights if single else None,
        largest_material=max(parts, key=lambda p: p.tri_count).largest_material,
    )

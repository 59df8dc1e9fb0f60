"""The default avatar's surface fields: tangents, painted textures and wrinkle maps, zone
masks and regions."""

from __future__ import annotations

import numpy as np

from capture2face.rig import features, maps, mesh_ops
from capture2face.rig.avatar.face_mesh import FaceMesh
from capture2face.rig.avatar.layout import Head, f32
from capture2face.rig.avatar.parts import hair_grid, jaw_shadow_grid
from capture2face.rig.avatar.poses import zone_table
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES
from capture2face.topology import MOUTH_CORNERS


def map_fields(face: FaceMesh, all_pos: np.ndarray, all_uv: np.ndarray, all_tri: np.ndarray,
                material: np.ndarray, rest_normals: np.ndarray, iris_theta: dict, head: Head,
                morph_names: list[str]) -> dict:
    """The FaceRig's tangents, textures, zones and regions."""
    # Regions and zones from one UV layout.
    layout = features.feature_layout(face.canonical_uvs)
    region_weights = features.region_fields(all_uv[:, 0], all_uv[:, 1], layout) * (material == 0)
    table = zone_table(morph_names)

    tangents = mesh_ops.uv_tangents(all_pos, rest_normals, all_uv, all_tri)
    hv, edge, n_edge, pos = head.verts, head.edge, head.n_edge, face.pos
    textures = maps.build_maps(face.canonical_uvs, all_uv, all_tri, material, iris_theta,
                               head_hair=hair_grid(hv, n_edge),
                               head_shadow=jaw_shadow_grid(hv, n_edge, float(pos[list(MOUTH_CORNERS), 1].mean())),
                               head_edge_uvs=all_uv[edge[np.arange(n_edge + 1) % n_edge]])
    return {"tangents": f32(tangents), "albedo": textures["albedo"], "normal_map": textures["normal"],
            "wrinkle_maps": np.stack([textures["stretch"], textures["compress"]]),
            "zone_names": list(ZONE_NAMES), "zone_masks": textures["zones"], "zone_table": f32(table),
            "region_names": list(REGION_NAMES), "region_weights": f32(region_weights)}

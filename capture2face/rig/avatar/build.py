"""The default avatar built from scratch: the face's skin, then the parts after it, then
skinning, morphs, bones and maps over all vertices."""

from __future__ import annotations

import numpy as np

from capture2face.rig import mesh_ops
from capture2face.rig.avatar.face_mesh import build_face_mesh
from capture2face.rig.avatar.layout import (
    Parts,
    add_ears,
    add_eyes,
    add_head_shell,
    add_mouth_interior,
    add_teeth,
    f32,
    shared_position_ids,
)
from capture2face.rig.avatar.morphs import MorphBuilder, all_morphs, build_morphs
from capture2face.rig.avatar.poses import bone_fields
from capture2face.rig.avatar.skinning import part_skinning, skin_weights
from capture2face.rig.avatar.textures import map_fields
from capture2face.rig.avatar.vertex_sets import vertex_sets
from capture2face.rig.face_rig import FaceRig


def build_avatar(variant: str = "default") -> FaceRig:
    """Build the avatar from scratch (no cache). See
    :func:`~capture2face.rig.avatar.cache.default_avatar`."""
    face = build_face_mesh(variant)
    mb = MorphBuilder(face.pos, face.tris, face.normals)
    sets = vertex_sets(face, mb)
    joints, weights = skin_weights(face.pos, mb.graph, face.loops, sets["lowerness"])
    skin_morphs = build_morphs(mb, sets, face.mirror)

    parts = Parts()
    parts.add(face.pos, face.uvs, face.tris, 0)
    eyes = add_eyes(parts, face.pos, sets["eye"])
    mouth = add_mouth_interior(parts, face.pos, sets)
    teeth = add_teeth(parts, face.pos, sets["lip_loop"])
    head = add_head_shell(parts, face.pos, face.loops)
    ears_start = add_ears(parts, face.pos, head)
    all_pos, all_uv, all_tri, material = parts.stack()
    V = len(all_pos)
    eye_vertex_side = np.full(V, -1, np.int8)
    eye_vertex_side[eyes.start:eyes.start + len(eyes.side)] = eyes.side

    all_joints, all_weights = part_skinning(joints, weights, mouth, teeth, head, V - ears_start)
    position_ids = shared_position_ids(V, head)
    morph_names, mp = all_morphs(skin_morphs, V, mouth, teeth, head)
    rest_normals = mesh_ops.welded_normals(all_pos, all_tri, position_ids)
    morphed_normals = mesh_ops.welded_normals(all_pos[None] + mp, all_tri, position_ids)
    mn = morphed_normals - rest_normals[None]

    return FaceRig(
        name="default" if variant == "default" else f"default_{variant}",
        vertices=f32(all_pos), normals=f32(rest_normals), uvs=f32(all_uv),
        triangles=all_tri, position_ids=position_ids, material=material,
        landmark_vertices=eyes.landmark_vertices,
        skin_joints=all_joints, skin_weights=all_weights,
        morph_names=morph_names, morph_positions=f32(mp), morph_normals=f32(mn),
        **bone_fields(all_pos, morph_names),
        **map_fields(face, all_pos, all_uv, all_tri, material, rest_normals, eyes.iris_theta, head, morph_names),
        eye_centres=f32(eyes.centres), eye_vertex_side=eye_vertex_side, double_sided=False,
    )


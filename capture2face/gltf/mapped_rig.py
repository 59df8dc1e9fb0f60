"""The mapping JSON applied to an imported rig: bones tied to landmarks, bone groups,
landmark vertices, reference poses and zone table rows (what the character's own file
says; nothing lent from another character)."""

from __future__ import annotations

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.mapping import Mapping
from capture2face.rig.face_rig import FaceRig
from capture2face.topology import N_LANDMARKS


def _bone_index(rig: FaceRig, mapping: Mapping):
    alias = {n: i for i, n in enumerate(rig.bone_names)}
    if mapping.head_bone:
        alias[mapping.head_bone] = 0

    def bone(name: str) -> int:
        if name not in alias:
            raise CaptureError(f"mapping: '{name}' is not a bone of the character")
        return alias[name]

    return bone


def _landmarks(rig: FaceRig, mapping: Mapping, bone) -> FaceRig:
    """Bones -> landmarks, bone groups and landmark vertices."""
    landmarks = rig.bone_landmarks.copy()
    for name, lm in mapping.bones.items():  # landmarks in range: the mapping's check
        landmarks[bone(name)] = int(lm)
    groups = np.arange(rig.n_bones, dtype=np.int32)
    for gid, members in enumerate(mapping.bone_groups):
        for name in members:
            groups[bone(name)] = rig.n_bones + gid
    _, groups = np.unique(groups, return_inverse=True)
    lmv = rig.landmark_vertices.copy()
    for lm, v in mapping.landmark_vertices.items():
        if not (0 <= int(lm) < N_LANDMARKS and 0 <= int(v) < rig.n_vertices):
            raise CaptureError(f"mapping: landmark_vertices entry {lm}: {v} is out of range")
        lmv[int(lm)] = int(v)
    return rig.replace(bone_landmarks=landmarks.astype(np.int32), bone_groups=groups.astype(np.int32),
                       landmark_vertices=lmv)


def _poses(rig: FaceRig, mapping: Mapping, bone) -> FaceRig:
    """"stretch", "compress" and the mapping's poses: bone positions, morph weights, maps."""
    poses = mapping.poses
    pose_names = list(dict.fromkeys(["stretch", "compress", *poses]))
    pose_bones = np.repeat(rig.bone_rest[None], len(pose_names), 0).astype(np.float32)
    pose_morph = np.zeros((len(pose_names), rig.n_morphs), np.float32)
    pose_maps = np.zeros(len(pose_names), np.int32)
    for p, pname in enumerate(pose_names):
        spec = poses.get(pname, {})
        for name, off in spec.get("offsets", {}).items():
            pose_bones[p, bone(name)] = rig.bone_rest[bone(name)] + np.asarray(off, np.float32)
        for name, xyz in spec.get("positions", {}).items():
            pose_bones[p, bone(name)] = np.asarray(xyz, np.float32)
        for mname, wv in spec.get("morphs", {}).items():
            if mname in rig.morph_names:
                pose_morph[p, rig.morph_index(mname)] = float(wv)
        wmap = spec.get("wrinkle_map", pname)
        if wmap in rig.wrinkle_map_names:
            pose_maps[p] = rig.wrinkle_map_names.index(wmap)
        elif "wrinkle_map" in spec:
            raise CaptureError(f"mapping: pose '{pname}' names wrinkle map '{wmap}', which is not in 'wrinkle_maps'")
    return rig.replace(pose_names=pose_names, pose_bones=pose_bones, pose_morph_weights=pose_morph,
                       pose_maps=pose_maps)


def zone_table_names(mapping: Mapping) -> set[str]:
    """The morph names (lower case) whose zone table rows the mapping gives."""
    return {str(k).lower() for k in mapping.zone_table}


def posed_names(mapping: Mapping) -> set[str]:
    """The poses whose bone motion the mapping gives (offsets or positions)."""
    return {p for p, spec in mapping.poses.items() if spec.get("offsets") or spec.get("positions")}


def apply_mapping(rig: FaceRig, mapping: Mapping) -> FaceRig:
    """Bones -> landmarks, groups, landmark vertices, poses and zone table rows from the
    mapping JSON."""
    bone = _bone_index(rig, mapping)
    rig = _poses(_landmarks(rig, mapping, bone), mapping, bone)
    table = rig.zone_table.copy()
    given_table = {str(k).lower(): v for k, v in mapping.zone_table.items()}
    for i, mname in enumerate(rig.morph_names):
        if mname.lower() in given_table:  # 8 numbers: the mapping's check
            table[i] = np.asarray(given_table[mname.lower()], np.float32)
    return rig.replace(zone_table=table)

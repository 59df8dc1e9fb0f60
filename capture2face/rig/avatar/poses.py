"""The default avatar's wrinkle poses: the reference poses as bone displacements, the morphs
shown with them, and which expression folds or stretches which wrinkle zone."""

from __future__ import annotations

import numpy as np

from capture2face.rig.avatar.bones import BONES
from capture2face.rig.avatar.layout import f32
from capture2face.rig.face_rig import ZONE_NAMES

# Reference poses as bone displacements (cm) for the subject's left side and the middle;
# "_R" bones get the mirror image (x negated). Every face bone moves in both poses.
_POSES = {
    "stretch": {  # brows raised, eyes wide, mouth open
        "brow_inner": (0.0, 1.0, 0.1), "brow_mid": (0.0, 1.1, 0.05), "brow_outer": (0.0, 0.9, 0.0),
        "eyelid_upper": (0.0, 0.35, 0.05), "eyelid_lower": (0.0, -0.2, 0.0),
        "cheek": (0.0, -0.35, -0.05), "cheek_upper": (0.0, -0.25, 0.0), "nose_wing": (0.0, -0.25, 0.0),
        "lip_upper_C": (0.0, 0.3, 0.0), "lip_upper": (0.0, 0.3, 0.0),
        "mouth_corner": (-0.2, -0.6, -0.1),
        "lip_lower_C": (0.0, -1.0, -0.2), "lip_lower": (0.0, -0.9, -0.2),
        "jaw": (0.0, -0.8, -0.25),
    },
    "compress": {  # brows down and together, squint, lips puckered
        "brow_inner": (-0.35, -0.45, 0.1), "brow_mid": (-0.25, -0.5, 0.05), "brow_outer": (-0.1, -0.45, 0.0),
        "eyelid_upper": (0.0, -0.3, 0.0), "eyelid_lower": (0.0, 0.25, 0.05),
        "cheek": (0.0, 0.4, 0.15), "cheek_upper": (0.0, 0.35, 0.1), "nose_wing": (0.0, 0.3, 0.1),
        "lip_upper_C": (0.0, -0.1, 0.6), "lip_upper": (-0.25, -0.1, 0.55),
        "mouth_corner": (-0.8, 0.0, 0.3),
        "lip_lower_C": (0.0, 0.15, 0.6), "lip_lower": (-0.25, 0.15, 0.55),
        "jaw": (0.0, 0.35, 0.25),
    },
}


# Morph weights shown with each pose (display only; pose evaluation uses bones).
_POSE_MORPHS = {
    "stretch": {"eyeWideLeft": 0.5, "eyeWideRight": 0.5, "jawOpen": 0.3},
    "compress": {"eyeSquintLeft": 0.5, "eyeSquintRight": 0.5, "mouthPucker": 0.5,
                 "browDownLeft": 0.3, "browDownRight": 0.3},
}


# Expression x zone table (Oat's signs: +1 compress map, -1 stretch map). Sided entries
# are written for "Left" and mirrored for "Right".
_ZONE_TABLE = {
    "browInnerUp": {"forehead_left": -1.0, "forehead_right": -1.0, "glabella": -0.5},
    "browOuterUpLeft": {"forehead_left": -1.0},
    "browDownLeft": {"glabella": 0.6, "forehead_left": 0.3},
    "eyeSquintLeft": {"crows_feet_left": 1.0},
    "eyeBlinkLeft": {"crows_feet_left": 0.3},
    "eyeWideLeft": {"forehead_left": -0.4, "crows_feet_left": -0.3},
    "mouthSmileLeft": {"crows_feet_left": 0.5, "nasolabial_left": 1.0},
    "mouthFrownLeft": {"chin": 0.5, "nasolabial_left": -0.3},
    "mouthUpperUpLeft": {"nasolabial_left": 0.5},
    "mouthLowerDownLeft": {"chin": -0.3},
    "noseSneerLeft": {"glabella": 0.5, "nasolabial_left": 0.6},
    "mouthPucker": {"chin": 0.8, "nasolabial_left": -0.3, "nasolabial_right": -0.3},
    "mouthFunnel": {"chin": 0.4},
    "jawOpen": {"chin": -0.6, "nasolabial_left": -0.4, "nasolabial_right": -0.4},
    "cheekPuff": {"nasolabial_left": -0.6, "nasolabial_right": -0.6, "chin": -0.2},
}


def bone_fields(all_pos: np.ndarray, morph_names: list[str]) -> dict:
    """The FaceRig's bone and reference-pose fields."""
    # Bones.
    bone_names = [b.name for b in BONES]
    bone_landmarks = np.array([b.landmark for b in BONES], np.int32)
    bone_rest = np.zeros((len(BONES), 3))
    bone_rest[1:] = all_pos[bone_landmarks[1:]]
    group_names = [b.group or b.name for b in BONES]
    bone_groups = np.unique(group_names, return_inverse=True)[1].astype(np.int32)

    pose_names = ["stretch", "compress"]
    pose_bones = np.stack([bone_rest + _pose_displacements(p) for p in pose_names])
    pose_morph_weights = np.zeros((2, len(morph_names)))
    for p, pname in enumerate(pose_names):
        for mname, w in _POSE_MORPHS[pname].items():
            pose_morph_weights[p, morph_names.index(mname)] = w
    return {"bone_names": bone_names, "bone_rest": f32(bone_rest),
            "bone_parents": np.array([-1] + [0] * (len(BONES) - 1), np.int32),
            "bone_landmarks": bone_landmarks, "bone_groups": bone_groups,
            "pose_names": pose_names, "pose_bones": f32(pose_bones), "pose_morph_weights": f32(pose_morph_weights),
            "pose_maps": np.array([0, 1], np.int32), "wrinkle_map_names": ["stretch", "compress"]}


def _pose_displacements(pose: str) -> np.ndarray:
    table = _POSES[pose]
    out = np.zeros((len(BONES), 3))
    for i, b in enumerate(BONES[1:], start=1):
        key = b.name if b.name in table else b.name.rsplit("_", 1)[0]  # "lip_upper_C" or "lip_upper"
        d = np.array(table[key], float)
        if b.name.endswith("_R"):
            d = d * np.array([-1.0, 1.0, 1.0])
        out[i] = d
    return out


def zone_table(morph_names: list[str]) -> np.ndarray:
    table = np.zeros((len(morph_names), len(ZONE_NAMES)))

    def swap(z):
        return z.replace("left", "@").replace("right", "left").replace("@", "right")

    for name, entries in _ZONE_TABLE.items():
        rows = [(name, entries)]
        if name.endswith("Left"):
            rows.append((name[:-4] + "Right", {swap(z): w for z, w in entries.items()}))
        for row_name, row in rows:
            if row_name in morph_names:
                for zone, w in row.items():
                    table[morph_names.index(row_name), ZONE_NAMES.index(zone)] = w
    return table

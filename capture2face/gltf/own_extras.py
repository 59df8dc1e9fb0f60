"""A .glb written by :func:`capture2face.gltf.export_glb`: the rest of its FaceRig (what
glTF has no slot for) in ``extras.capture2face``, restored exactly."""

from __future__ import annotations

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import EXTRAS_FORMAT, EXTRAS_KEY
from capture2face.gltf.surface import Surface
from capture2face.rig.face_rig import FaceRig


def own_extras(g: dict) -> dict | None:
    """Our extras of document ``g``, or None where it is not our own export. Our eye
    joints (the skin's last joints) turn the eyeballs; they are no bones: they are taken
    off the skins' joint lists here."""
    ours = g.get("extras", {}).get(EXTRAS_KEY) if isinstance(g.get("extras"), dict) else None
    if ours is not None and ours.get("format") != EXTRAS_FORMAT:
        ours = None
    if ours and ours.get("eye_joints"):
        for skin in g.get("skins", []):
            skin["joints"] = skin["joints"][: len(ours["bone_names"])]
    return ours


def _eyes(rig: FaceRig, ours: dict, surface: Surface) -> dict:
    """Eyeball vertices: skinned to an eye joint (indices after the bones), back to the head."""
    if not (ours.get("eye_joints") and surface.joints is not None):
        return {}
    raw = np.asarray(surface.joints, np.int64)
    heavy = np.take_along_axis(raw, np.argmax(surface.weights, axis=1)[:, None], 1)[:, 0]
    side = np.where(heavy >= rig.n_bones, heavy - rig.n_bones, -1).astype(np.int8)
    joints, weights = rig.skin_joints.copy(), rig.skin_weights.copy()
    joints[side >= 0], weights[side >= 0] = 0, [1.0, 0.0, 0.0, 0.0]
    return {"eye_centres": np.asarray(ours["eye_centres_cm"], np.float32).reshape(2, 3),
            "eye_vertex_side": side, "skin_joints": joints, "skin_weights": weights}


def apply_own_extras(rig: FaceRig, ours: dict, surface: Surface) -> FaceRig:
    """A capture2face export: restore what glTF has no slot for, exactly."""
    if list(ours["bone_names"]) != rig.bone_names:
        raise CaptureError("the .glb's capture2face extras do not match its skin's joints")
    regions = np.zeros((len(ours["region_names"]), rig.n_vertices), np.float32)
    if surface.regions is not None:
        regions = np.ascontiguousarray(surface.regions[:, : len(regions)].T).astype(np.float32)
    P = len(ours["pose_names"])
    eyes = _eyes(rig, ours, surface)
    if "landmark_faces" in ours and "landmark_bary" in ours:  # landmarks on the surface
        eyes.update(landmark_faces=np.asarray(ours["landmark_faces"], np.int32).reshape(-1, 3),
                    landmark_bary=np.asarray(ours["landmark_bary"], np.float32).reshape(-1, 3))
    return rig.replace(
        **eyes,
        bone_rest=np.asarray(ours["bone_rest_cm"], np.float32).reshape(-1, 3),
        bone_parents=np.asarray(ours["bone_parents"], np.int32),
        bone_landmarks=np.asarray(ours["bone_landmarks"], np.int32),
        bone_groups=np.asarray(ours["bone_groups"], np.int32),
        landmark_vertices=np.asarray(ours["landmark_vertices"], np.int32),
        pose_names=list(ours["pose_names"]),
        pose_bones=np.asarray(ours["pose_bones_cm"], np.float32).reshape(P, rig.n_bones, 3),
        pose_morph_weights=np.asarray(ours["pose_morph_weights"], np.float32).reshape(P, rig.n_morphs),
        pose_maps=np.asarray(ours["pose_maps"], np.int32),
        zone_names=list(ours["zone_names"]),
        zone_table=np.asarray(ours["zone_table"], np.float32).reshape(rig.n_morphs, -1),
        region_names=list(ours["region_names"]), region_weights=regions,
    )

"""Where a rig's tracked feature points are: the tracker landmarks on its skin or bones, and
the automatic feature bones of an ARKit character (:mod:`capture2face.character.auto_wrinkles`)."""

from __future__ import annotations

import numpy as np

from capture2face.errors import CaptureError
from capture2face.rig.face_rig import FaceRig, landmark_points, landmark_support

# Bone-name prefix of automatic feature bones: they measure wrinkle influences, never move.
AUTO_PREFIX = "auto_feature/"


def feature_correspondence(rig) -> tuple[np.ndarray, np.ndarray, bool]:
    """Which tracker landmarks the rig has, and where.

    Returns:
        (landmarks (N,), target points (N, 3), per_vertex): with per-landmark vertices
        (``per_vertex`` True) every landmark that sits on the skin, at its point
        (:func:`~capture2face.rig.face_rig.landmark_points`: its vertex, or its point on a
        triangle); otherwise the bones' landmarks and the bones' rest positions.
    """
    lv = np.asarray(rig.landmark_vertices)
    # Skin only: iris landmarks follow the gaze, which the rig's eyeballs do not.
    has = np.flatnonzero(lv >= 0)
    has = has[np.asarray(rig.material)[lv[has]] == 0]
    if len(has) >= 3 * max(1, rig.n_bones - 1):
        return has, landmark_points(rig, rig.vertices, has).astype(np.float64), True
    bones = np.flatnonzero(np.asarray(rig.bone_landmarks) >= 0)
    if len(bones) < 4:
        raise CaptureError(f"character '{rig.name}' has too few tracked feature points to retarget onto")
    return np.asarray(rig.bone_landmarks)[bones], rig.bone_rest[bones].astype(np.float64), False


def feature_positions(rig: FaceRig, blend_weights: np.ndarray) -> np.ndarray:
    """(F, B, 3) float32 bone positions for the influences: the rest positions, with each
    automatic feature bone at its landmark's surface point deformed by the frame's morph
    weights.

    Args:
        blend_weights: (F, M) morph weights.
    """
    weights = np.asarray(blend_weights, np.float32)
    out = np.repeat(rig.bone_rest[None].astype(np.float32), len(weights), 0)
    auto = [b for b, n in enumerate(rig.bone_names) if n.startswith(AUTO_PREFIX)]
    if not auto:
        return out
    verts, bary, _ = landmark_support(rig, rig.bone_landmarks[auto])  # its triangle, or its vertex
    deltas = np.einsum("mnjc,nj->mnc", rig.morph_positions[:, verts], bary.astype(np.float32))
    deltas = deltas.reshape(rig.n_morphs, -1).astype(np.float32)  # (M, n*3)
    out[:, auto] += (weights @ deltas).reshape(len(weights), len(auto), 3)
    return out


def landmark_basis(rig: FaceRig, landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the rig's tracker landmarks sit and how its morphs move them: the linear model
    an ARKit character's morph weights are solved through.

    Args:
        landmarks: (N,) tracker landmark indices (each with a vertex on the rig).
    Returns:
        rest (N, 3) float64 positions and deltas (M, N, 3) float64 per morph target.
    """
    verts, bary, _ = landmark_support(rig, landmarks)  # on their triangles (or vertices)
    rest = landmark_points(rig, rig.vertices.astype(np.float64), landmarks)
    deltas = np.einsum("mnjc,nj->mnc", rig.morph_positions[:, verts].astype(np.float64), bary)
    return rest, deltas

"""Automatic wrinkle influences (Dutreve et al. 2009, §5.1-5.2).

Pure functions over arrays: bone positions in, influences out. The same code computes
the pipeline's influences and the synthetic ground truth, so the formula lives once.
"""

from __future__ import annotations

import numpy as np

from capture2face.rig.face_rig import FaceRig

# Bones that move less than this (cm) between rest and a reference pose take no part in
# that pose: their projection would divide by ~0.
_MIN_POSE_TRAVEL_CM = 1e-4


def pose_influences(bone_positions: np.ndarray, bone_rest: np.ndarray, pose_bones: np.ndarray) -> np.ndarray:
    """Per-bone influence of each reference pose: the clamped projection of the bone's
    displacement onto its rest -> reference segment.

    ``a = dot(J_f - J_0, J_k - J_0) / |J_k - J_0|^2`` clamped to [0, 1]. The paper prints
    the norm in the denominator; the square is what makes a == 1 exactly at the pose.

    Args:
        bone_positions: (F, B, 3) bone positions in head coordinates.
        bone_rest: (B, 3) rest positions.
        pose_bones: (P, B, 3) bone positions of the reference poses.
    Returns:
        (F, P, B) float32 influences in [0, 1]; 0 for bones that do not move in a pose.
    """
    moved = np.asarray(bone_positions, np.float64) - bone_rest  # (F, B, 3)
    segment = np.asarray(pose_bones, np.float64) - bone_rest  # (P, B, 3)
    length2 = np.einsum("pbc,pbc->pb", segment, segment)  # (P, B)
    active = length2 > _MIN_POSE_TRAVEL_CM**2
    proj = np.einsum("fbc,pbc->fpb", moved, segment) / np.where(active, length2, 1.0)
    return np.where(active, np.clip(proj, 0.0, 1.0), 0.0).astype(np.float32)


def group_influences(influences: np.ndarray, bone_groups: np.ndarray) -> np.ndarray:
    """Replace each bone's influence by the mean over its group (Dutreve §5.1).

    Args:
        influences: (F, P, B).
        bone_groups: (B,) int group id per bone.
    Returns:
        (F, P, B) float32.
    """
    ids, inverse = np.unique(bone_groups, return_inverse=True)
    membership = np.zeros((len(bone_groups), len(ids)))
    membership[np.arange(len(bone_groups)), inverse] = 1.0
    group_mean = influences @ membership / membership.sum(0)  # (F, P, G)
    return group_mean[..., inverse].astype(np.float32)


def rest_influence(influences: np.ndarray) -> np.ndarray:
    """(F, P, B) -> (F, B): ``max(0, 1 - sum_k a_k)``."""
    return np.maximum(0.0, 1.0 - influences.sum(axis=1)).astype(np.float32)


def rig_influences(bone_positions: np.ndarray, rig: FaceRig) -> np.ndarray:
    """(F, B, 3) bone positions -> (F, P, B) grouped per-bone influences for ``rig``."""
    raw = pose_influences(bone_positions, rig.bone_rest, rig.pose_bones)
    return group_influences(raw, rig.bone_groups)


def vertex_influences(influences: np.ndarray, skin_weights: np.ndarray) -> np.ndarray:
    """Bone masks (§5.2): ``Inf(v, P_k) = sum_i w_vi * I_Pk(J_i)``.

    Args:
        influences: (F, P, B) per-bone influences.
        skin_weights: (V, B) dense convex skinning weights.
    Returns:
        (F, P, V) float32 per-vertex influences in [0, 1].
    """
    return np.einsum("fpb,vb->fpv", influences, skin_weights).astype(np.float32)


def region_influence(influences: np.ndarray, rig: FaceRig) -> np.ndarray:
    """Mean per-vertex influence over each of the rig's regions.

    Args:
        influences: (F, P, B) per-bone influences.
    Returns:
        (F, R, P) float32, rows in ``rig.region_names`` order.
    """
    # Averaging per-vertex influence over a region is linear, so fold the region
    # weights into the skinning weights first: (R, V) @ (V, B) -> (R, B).
    region = rig.region_weights / np.maximum(rig.region_weights.sum(1, keepdims=True), 1e-12)
    region_bone = region @ rig.dense_skin_weights()  # (R, B)
    return np.einsum("fpb,rb->frp", influences, region_bone).astype(np.float32)


def zone_weights(blend_weights: np.ndarray, zone_table: np.ndarray) -> np.ndarray:
    """Zone weights for the ``zones`` driver (Oat / Jimenez).

    Args:
        blend_weights: (F, M) morph weights.
        zone_table: (M, 8) expression x zone table; signed, entries cancel.
    Returns:
        (F, 8) float32 in [-1, 1]: +1 blends the compress map, -1 the stretch map.
    """
    return np.clip(blend_weights @ zone_table, -1.0, 1.0).astype(np.float32)

"""CPU reference deformation: morph targets, then linear blend skinning.

Bones translate only (Dutreve), so skinning is ``v' = v_m + sum_i w_vi (J_i - J_i_rest)``
and does not rotate normals: the deformed normals are the morphed normals
``normalize(n + sum_k w_k dn_k)``, exactly what the GPU path computes. This module is
the ground truth the renderer is tested against. Eyeballs then turn rigidly about their
centres (``eye_rotation``, :func:`capture2face.rig.face_rig.turn_eyes`).
"""

from __future__ import annotations

import numpy as np

from capture2face.rig.face_rig import FaceRig, turn_eyes


def deform(rig: FaceRig, bone_positions: np.ndarray, blend_weights: np.ndarray,
           eye_rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Deform the rig's mesh.

    Args:
        bone_positions: (B, 3) or (F, B, 3) bone positions in head coordinates (cm).
        blend_weights: (M,) or (F, M) morph-target weights.
        eye_rotation: (2, 2) or (F, 2, 2) yaw, pitch (degrees) of the right and left
            eye, or None (eyes straight ahead).
    Returns:
        (positions, normals): (V, 3) each, or (F, V, 3) for batched input; float32.
    """
    bones = np.asarray(bone_positions, np.float64)
    weights = np.asarray(blend_weights, np.float64)
    single = bones.ndim == 2
    if single != (weights.ndim == 1):
        raise ValueError("bone_positions and blend_weights must both be single frames or both batched")
    if single:
        bones, weights = bones[None], weights[None]
    if bones.shape[1:] != (rig.n_bones, 3) or weights.shape[1:] != (rig.n_morphs,) or len(bones) != len(weights):
        raise ValueError(f"expected (F, {rig.n_bones}, 3) bones and (F, {rig.n_morphs}) weights, "
                         f"got {bones.shape} and {weights.shape}")
    # Morph targets (Yang): P = P0 + sum_k w_k dP_k, the same for normals.
    flat_pos = rig.morph_positions.reshape(rig.n_morphs, -1).astype(np.float64)
    flat_nrm = rig.morph_normals.reshape(rig.n_morphs, -1).astype(np.float64)
    positions = rig.vertices.astype(np.float64) + (weights @ flat_pos).reshape(len(weights), -1, 3)
    normals = rig.normals.astype(np.float64) + (weights @ flat_nrm).reshape(len(weights), -1, 3)
    # Translation-only LBS: gather the 4 joints' translations per vertex.
    translation = bones - rig.bone_rest.astype(np.float64)  # (F, B, 3)
    per_joint = translation[:, rig.skin_joints]  # (F, V, 4, 3)
    positions += np.einsum("vj,fvjc->fvc", rig.skin_weights.astype(np.float64), per_joint)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    if eye_rotation is not None:
        turn_eyes(rig, positions, normals, np.asarray(eye_rotation, np.float64).reshape(-1, 2, 2))
    positions, normals = positions.astype(np.float32), normals.astype(np.float32)
    return (positions[0], normals[0]) if single else (positions, normals)

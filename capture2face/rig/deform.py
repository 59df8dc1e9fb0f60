"""CPU reference deformation: morph targets, then linear blend skinning.

Bones translate only (Dutreve), so skinning is ``v' = v_m + sum_i w_vi (J_i - J_i_rest)``
and does not rotate normals: the deformed normals are the morphed normals
``normalize(n + sum_k w_k dn_k)``, exactly what the GPU path computes; a rig with
``normals_from_shape`` turns its rest normals by the deformed shape instead
(:class:`ShapeNormals`). This module is the ground truth the renderer is tested against.
Eyeballs then turn rigidly about their centres (``eye_rotation``,
:func:`capture2face.rig.face_rig.turn_eyes`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from capture2face.rig.face_rig import FaceRig, turn_eyes


class ShapeNormals:
    """Normals of a rig's deformed shape (``FaceRig.normals_from_shape``): its rest normals
    plus the change of its smooth, area-weighted normals over shared positions (no seam at
    UV splits) from the rest shape to the deformed one. Exact under any mix of morphs and
    bones, and the rest normals (hard edges, the file's own) stand wherever nothing moves."""

    def __init__(self, rig: FaceRig):
        self._ids = np.asarray(rig.position_ids, np.int64)
        tris = np.asarray(rig.triangles, np.int64)
        self._a, self._b, self._c = tris[:, 0], tris[:, 1], tris[:, 2]
        n = int(self._ids.max()) + 1 if len(self._ids) else 0
        # position id x triangle: each triangle's normal summed onto its corners' positions
        self._incidence = sp.csr_matrix((np.ones(tris.size, np.float32), (self._ids[tris].ravel(),
                                         np.repeat(np.arange(len(tris)), 3))), shape=(n, len(tris)))
        self._rest_normals = np.asarray(rig.normals, np.float32)
        self._rest = self.smooth(rig.vertices)

    def smooth(self, positions: np.ndarray) -> np.ndarray:
        """(V, 3) float32 smooth unit normals of ``positions`` (V, 3); 0 on a vertex in no
        triangle."""
        p = np.asarray(positions, np.float32)
        a = p[self._a]
        face = np.cross(p[self._b] - a, p[self._c] - a)  # length = twice the area: area-weighted
        n = self._incidence @ face
        n /= np.maximum(np.sqrt(np.einsum("vc,vc->v", n, n)), 1e-12)[:, None]
        return n[self._ids]

    def __call__(self, positions: np.ndarray) -> np.ndarray:
        """(V, 3) float32 unit normals of the rig deformed to ``positions`` (V, 3)."""
        n = self._rest_normals + (self.smooth(positions) - self._rest)
        n /= np.maximum(np.sqrt(np.einsum("vc,vc->v", n, n)), 1e-12)[:, None]
        return n


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
    if rig.normals_from_shape:
        shaped = ShapeNormals(rig)
        normals = np.stack([shaped(p) for p in positions])
    if eye_rotation is not None:
        turn_eyes(rig, positions, normals, np.asarray(eye_rotation, np.float64).reshape(-1, 2, 2))
    positions, normals = positions.astype(np.float32), normals.astype(np.float32)
    return (positions[0], normals[0]) if single else (positions, normals)

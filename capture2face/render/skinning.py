"""The rig's deformation in NumPy, prepared once per renderer: morph targets (Yang), then
translation-only linear blend skinning (Dutreve), as ``capture2face.rig.deform`` defines
it, then the eyeballs' turn (``FaceRig.eye_centres``) and, for a character with a head
joint (``FaceRig.head_weights``), the head rotation blended by each vertex's share of it;
float32, over the active morphs only (~1 ms for the default head, against ~5 ms for the
batched reference).
"""

from __future__ import annotations

import numpy as np
from threadpoolctl import ThreadpoolController

from capture2face.rig.deform import ShapeNormals
from capture2face.rig.face_rig import FaceRig, turn_eyes

# The per-frame products are small (V x 26 bones, a few active morphs x 3V): one BLAS
# thread does them in ~1 ms, while a threaded BLAS on a loaded 2-core machine spent 8-17
# ms synchronising once the default head's 5.8k vertices crossed its threading threshold.
# A controller made once limits the threads for ~7 us a call.
_BLAS = ThreadpoolController()


def _one_blas_thread():
    return _BLAS.limit(limits=1, user_api="blas")


class Deformer:
    """``deformer(bones, weights) -> (positions, normals)`` for one rig."""

    def __init__(self, rig: FaceRig):
        self.n_vertices, self.n_bones, self.n_morphs = rig.n_vertices, rig.n_bones, rig.n_morphs
        self._vertices = np.ascontiguousarray(rig.vertices, np.float32).ravel()
        self._normals = np.ascontiguousarray(rig.normals, np.float32).ravel()
        self._morph_positions = np.ascontiguousarray(rig.morph_positions, np.float32).reshape(rig.n_morphs, -1)
        self._morph_normals = np.ascontiguousarray(rig.morph_normals, np.float32).reshape(rig.n_morphs, -1)
        self._bone_rest = np.asarray(rig.bone_rest, np.float64)
        # Skinning as one (V, B) matrix: the 4 weights of each vertex in its joints' columns.
        self._skin = rig.dense_skin_weights()
        hw = getattr(rig, "head_weights", None)
        self._head = None if hw is None else np.asarray(hw, np.float32)[:, None]
        self._pivot = np.asarray(rig.bone_rest[0], np.float32)
        self._rig = rig
        self._shape_normals = ShapeNormals(rig) if rig.normals_from_shape else None

    def _turn(self, points: np.ndarray, rotation, about: np.ndarray | float) -> np.ndarray:
        """``points`` turned by ``rotation`` about ``about``, blended by the head weights."""
        if rotation is None or self._head is None:
            return points
        rot = np.asarray(rotation, np.float32)
        return points + self._head * ((points - about) @ rot.T + about - points)

    def _check(self, bone_positions, blend_weights) -> tuple[np.ndarray, np.ndarray]:
        bones = np.asarray(bone_positions, np.float64)
        weights = np.asarray(blend_weights, np.float32).ravel()
        if bones.shape != (self.n_bones, 3):
            raise ValueError(f"bone_positions must be ({self.n_bones}, 3), got {bones.shape}")
        if weights.shape != (self.n_morphs,):
            raise ValueError(f"blend_weights must be ({self.n_morphs},), got {weights.shape}")
        return bones, weights

    def positions(self, bone_positions: np.ndarray, blend_weights: np.ndarray, *,
                  eye_rotation: np.ndarray | None = None, head_rotation: np.ndarray | None = None) -> np.ndarray:
        """(V, 3) float32 deformed positions, head coordinates (cm); ``eye_rotation``
        (2, 2) yaw, pitch degrees per eye turns the eyeballs (None: straight ahead), then
        ``head_rotation`` (3, 3) turns the head joint's vertices about it (rigs with
        ``head_weights``)."""
        positions = self._shaped(bone_positions, blend_weights)
        turn_eyes(self._rig, positions, None, eye_rotation)
        return self._turn(positions, head_rotation, self._pivot)

    def _shaped(self, bone_positions: np.ndarray, blend_weights: np.ndarray) -> np.ndarray:
        """(V, 3) float32 positions after the morphs and the skinning, before any turn."""
        bones, weights = self._check(bone_positions, blend_weights)
        active = np.flatnonzero(weights)
        with _one_blas_thread():
            positions = (self._vertices + weights[active] @ self._morph_positions[active]).reshape(-1, 3)
            positions += self._skin @ (bones - self._bone_rest).astype(np.float32)
        return positions

    def normals(self, blend_weights: np.ndarray, *, eye_rotation: np.ndarray | None = None,
                head_rotation: np.ndarray | None = None) -> np.ndarray:
        """(V, 3) float32 unit normals: translations leave them alone, morphs bend them
        (the eyes' turn turns the eyeballs', and the head rotation the head's)."""
        weights = np.asarray(blend_weights, np.float32).ravel()
        active = np.flatnonzero(weights)
        with _one_blas_thread():
            normals = (self._normals + weights[active] @ self._morph_normals[active]).reshape(-1, 3)
        normals /= np.maximum(np.sqrt(np.einsum("vc,vc->v", normals, normals)), 1e-12)[:, None]
        return self._turned_normals(normals, eye_rotation, head_rotation)

    def _turned_normals(self, normals: np.ndarray, eye_rotation, head_rotation) -> np.ndarray:
        turn_eyes(self._rig, None, normals, eye_rotation)
        if head_rotation is None or self._head is None:
            return normals
        # A vertex shared between head and body turns part way: normalise again.
        normals = self._turn(normals, head_rotation, 0.0)
        normals /= np.maximum(np.sqrt(np.einsum("vc,vc->v", normals, normals)), 1e-12)[:, None]
        return normals

    def skin(self, per_bone: np.ndarray) -> np.ndarray:
        """(V, K) float32 per-vertex blend ``sum_i w_vi * per_bone[J_i]`` of (B, K) values."""
        with _one_blas_thread():
            return self._skin @ np.asarray(per_bone, np.float32)

    def __call__(self, bone_positions: np.ndarray, blend_weights: np.ndarray,
                 *, eye_rotation: np.ndarray | None = None,
                 head_rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(positions, normals), (V, 3) float32 each."""
        if self._shape_normals is None:
            return (self.positions(bone_positions, blend_weights, eye_rotation=eye_rotation,
                                   head_rotation=head_rotation),
                    self.normals(blend_weights, eye_rotation=eye_rotation, head_rotation=head_rotation))
        positions = self._shaped(bone_positions, blend_weights)
        normals = self._turned_normals(self._shape_normals(positions), eye_rotation, head_rotation)
        turn_eyes(self._rig, positions, None, eye_rotation)
        return self._turn(positions, head_rotation, self._pivot), normals

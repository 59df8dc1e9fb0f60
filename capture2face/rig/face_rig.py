"""``FaceRig``: everything the pipeline knows about a character, as plain NumPy arrays.

Conventions shared by every stage (see docs/ARCHITECTURE.md):

* **Head coordinates** are those of MediaPipe's canonical face mesh, in centimetres:
  +x towards the subject's left, +y up, +z out of the face (towards a camera in front).
* **UVs** have their origin at the top-left of the texture (glTF / image convention):
  texel row = v * height.
* **Bones translate only** (Dutreve et al.): a bone's pose is its position in head
  coordinates; its skinning transform is the translation ``position - rest``.
  Bone 0 is the root ``head`` bone: it never moves in head coordinates and takes the
  skinning weight of everything far from the face's features.
* **Deformation order**: morph targets first, then linear blend skinning.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import numpy as np

from capture2face.io.npz import load_dataclass, save_dataclass
from capture2face.maths.rotations import rotation_ypr
from capture2face.topology import IOD_PAIR

FORMAT = "capture2face.FaceRig/1"

# The Jimenez et al. mask zones, in the order of the two RGBA mask textures (RGBA, RGBA).
ZONE_NAMES = [
    "forehead_left", "forehead_right", "glabella", "crows_feet_left",
    "crows_feet_right", "nasolabial_left", "nasolabial_right", "chin",
]

# Regions over which Animation.region_influence averages per-vertex influences.
REGION_NAMES = [
    "forehead", "glabella", "crows_feet_left", "crows_feet_right",
    "nasolabial_left", "nasolabial_right", "chin",
]


@dataclass
class FaceRig:
    """A skinned, morphable face with wrinkle maps.

    Shapes: V vertices, T triangles, B bones (bone 0 = root ``head``), M morph targets,
    P reference poses, K wrinkle maps, R regions, Z = 8 mask zones, L tracker landmarks
    (478 for MediaPipe), H x W texture size.

    Attributes:
        name: character name.
        vertices: (V, 3) float32 rest positions, head coordinates (cm).
        normals: (V, 3) float32 unit rest normals.
        uvs: (V, 2) float32 texture coordinates, origin top-left.
        tangents: (V, 4) float32 unit tangent (xyz) along +u and handedness w = +-1;
            bitangent = w * cross(normal, tangent).
        triangles: (T, 3) int32 vertex indices, counter-clockwise seen from outside.
        position_ids: (V,) int32; vertices that share a position (split at UV seams or
            material borders) share an id, so area-based wrinkles show no seam.
        material: (V,) uint8; 0 skin of the face, 1 eye, 2 mouth interior (dark cavity),
            3 teeth and tongue, 4 the rest of the head (scalp, ears, neck: shaded as skin,
            no wrinkles; framing and face size go by the face's skin alone).
        landmark_vertices: (L,) int32; the vertex that tracker landmark l sits on, or -1
            (with ``landmark_faces``: the nearest of its triangle's three).
        bone_names: B names; bone_names[0] == "head".
        bone_rest: (B, 3) float32 rest positions, head coordinates.
        bone_parents: (B,) int32 parent bone index, -1 for the root.
        bone_landmarks: (B,) int32 tracker landmark index each bone follows (-1 for head).
        bone_groups: (B,) int32 group id; bones with the same id share the mean of their
            pose influences (Dutreve §5.1). Ungrouped bones have an id of their own.
        skin_joints: (V, 4) int32 bone indices (unused slots point at bone 0 with weight 0).
        skin_weights: (V, 4) float32 convex weights (>= 0, each row sums to 1).
        morph_names: M morph-target names (ARKit names where one fits: "jawOpen", ...).
        morph_positions: (M, V, 3) float32 position deltas.
        morph_normals: (M, V, 3) float32 normal deltas.
        pose_names: P reference-pose names ("stretch", "compress").
        pose_bones: (P, B, 3) float32 bone positions of each reference pose.
        pose_morph_weights: (P, M) float32 morph weights that go with each pose (for
            showing the pose; pose evaluation uses bones only).
        pose_maps: (P,) int32 index into ``wrinkle_map_names`` of each pose's wrinkle map.
        wrinkle_map_names: K names ("stretch", "compress").
        albedo: (H, W, 3) uint8 sRGB colour.
        normal_map: (H, W, 3) uint8 tangent-space base normal map (n * 127.5 + 127.5).
        wrinkle_maps: (K, H, W, 3) uint8 tangent-space wrinkle normal maps, same encoding.
        zone_names: the 8 mask zone names (``ZONE_NAMES``).
        zone_masks: (H, W, 8) uint8 zone masks: channels 0-3 are the first RGBA mask,
            4-7 the second.
        zone_table: (M, 8) float32 expression x zone weights; rows follow ``morph_names``.
            A zone's weight is clamp(sum_m w_m * table[m, zone], -1, 1) with Oat's sign
            convention: +1 blends the "compress" map, -1 the "stretch" map; entries of
            opposite sign cancel.
        region_names: R region names (``REGION_NAMES``).
        region_weights: (R, V) float32 per-vertex membership in [0, 1] of each region.
        head_weights: (V,) float32 share of the head rotation each vertex takes (an
            imported character's skin weights on its head joint and the joints below
            it), or None: the head rotation turns the whole character (the camera).
        eye_centres: (2, 3) float32 rotation centres of the right (row 0: the subject's
            right, tracker landmarks 468-472) and left (row 1: 473-477) eyeballs, head
            coordinates; None for a rig without eyes that turn.
        eye_vertex_side: (V,) int8 0 on the right eyeball, 1 on the left, -1 elsewhere;
            those vertices turn rigidly about their eye's centre after skinning
            (``Animation.eye_rotation``, :func:`eye_rotation_matrices`). None with
            ``eye_centres``.
        landmark_faces: (L, 3) int32 vertex ids of the triangle each tracker landmark
            lies on (a point of the skin's surface, :func:`landmark_points`), or None: the
            landmarks sit on ``landmark_vertices``. Rows of landmarks without a vertex
            repeat ``landmark_vertices`` (-1).
        landmark_bary: (L, 3) float32 barycentric weights of that point on its triangle
            (rows sum to 1), or None with ``landmark_faces``.
        overlay_vertices: (V,) bool vertices of see-through overlays in front of the face
            (eyelash and hair cards, brows, glasses: alpha-masked or blended materials,
            meshes named so) that no landmark may land on, or None: none.
        double_sided: draw both sides of every triangle. False: back faces are culled,
            as glTF renders single-sided materials; the built-in avatar is closed and wound
            consistently (the back of its head never shows), and culling halves what a
            software renderer rasterizes.
        morph_rules: (M, 5) int8 VRM expression rules per morph (a .vrm's expressions are
            its morphs, :mod:`capture2face.gltf.vrm`): isBinary (0/1), overrideBlink,
            overrideLookAt, overrideMouth (0 none, 1 block, 2 blend) and the override group
            the morph is in (0 none, else the column of that override); None: no rules
            (:func:`capture2face.rig.morph_conventions.apply_rules`).
        alpha: (H, W) uint8 base-colour alpha (glTF: the texture's alpha times the factor's),
            read where ``alpha_mode`` says MASK or BLEND; None: every vertex opaque.
        alpha_mode: (V,) uint8 glTF alpha mode of each vertex's material: 0 OPAQUE, 1 MASK
            (drawn where alpha >= ``alpha_cutoff``: lashes, hair cards), 2 BLEND (blended
            over what is behind, after the opaque geometry: lenses, glass); a triangle's is
            its last vertex's, as for ``material``. None with ``alpha``.
        alpha_cutoff: (V,) float32 MASK cutoff of each vertex's material (glTF's
            ``alphaCutoff``, default 0.5). None with ``alpha``.
        look_ranges: (3, 91) float32 the look presets' weights at gaze angles of 0, 1,
            ..., 90 degrees (rows: LookLeft / LookRight, LookDown, LookUp) of a VRM whose
            gaze turns its look expressions, from its own range tables
            (:mod:`capture2face.rig.look_at`); None: its look presets (if any) follow their
            recipes.
        landmark_source: how a user's character's landmarks were found
            (:mod:`capture2face.character.landmark_sources`): "tracker front view",
            "morphs", "none"; "" where they were given (built-in avatars, mappings).
        eye_source: how ``eye_centres`` were found on a user's character ("VRM humanoid eye
            bones"); "" where they were given (built-in avatars, our own export) or there
            are none.
        normals_from_shape: the renderer turns the normals by the deformed shape itself
            (the rest ``normals`` plus the change of the smooth normals over
            ``position_ids``, rest to now) instead of by the sum of ``morph_normals``: a
            user's character, whose per-morph normal deltas (the file's, or derived one morph
            at a time) do not add up under combined morphs (they crease cheeks lit from
            above); False: the built-in avatars and our own export, drawn as they were.
    """

    name: str
    vertices: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    tangents: np.ndarray
    triangles: np.ndarray
    position_ids: np.ndarray
    material: np.ndarray
    landmark_vertices: np.ndarray
    bone_names: list[str]
    bone_rest: np.ndarray
    bone_parents: np.ndarray
    bone_landmarks: np.ndarray
    bone_groups: np.ndarray
    skin_joints: np.ndarray
    skin_weights: np.ndarray
    morph_names: list[str]
    morph_positions: np.ndarray
    morph_normals: np.ndarray
    pose_names: list[str]
    pose_bones: np.ndarray
    pose_morph_weights: np.ndarray
    pose_maps: np.ndarray
    wrinkle_map_names: list[str]
    albedo: np.ndarray
    normal_map: np.ndarray
    wrinkle_maps: np.ndarray
    zone_names: list[str]
    zone_masks: np.ndarray
    zone_table: np.ndarray
    region_names: list[str]
    region_weights: np.ndarray
    head_weights: np.ndarray | None = None
    eye_centres: np.ndarray | None = None
    eye_vertex_side: np.ndarray | None = None
    double_sided: bool = True
    alpha: np.ndarray | None = None
    alpha_mode: np.ndarray | None = None
    alpha_cutoff: np.ndarray | None = None
    landmark_faces: np.ndarray | None = None
    landmark_bary: np.ndarray | None = None
    overlay_vertices: np.ndarray | None = None
    morph_rules: np.ndarray | None = None
    look_ranges: np.ndarray | None = None
    landmark_source: str = ""
    eye_source: str = ""
    normals_from_shape: bool = False

    @property
    def has_eyes(self) -> bool:
        """The rig has eyeballs that turn with the gaze."""
        return self.eye_centres is not None and self.eye_vertex_side is not None

    # ---- derived quantities (never stored) ------------------------------------------
    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    @property
    def n_morphs(self) -> int:
        return len(self.morph_names)

    def dense_skin_weights(self) -> np.ndarray:
        """(V, B) float32 skinning weight matrix built from the 4-sparse form."""
        dense = np.zeros((self.n_vertices, self.n_bones), dtype=np.float32)
        rows = np.repeat(np.arange(self.n_vertices), self.skin_joints.shape[1])
        np.add.at(dense, (rows, self.skin_joints.ravel()), self.skin_weights.ravel())
        return dense

    def bone_index(self, name: str) -> int:
        return self.bone_names.index(name)

    def morph_index(self, name: str) -> int:
        return self.morph_names.index(name)

    def pose_index(self, name: str) -> int:
        return self.pose_names.index(name)

    def face_size(self) -> float:
        """Diagonal of the skin's bounding box (cm): the yardstick for tolerances (of every
        vertex where a mapping marks none as skin)."""
        skin = self.vertices[self.material == 0]
        skin = skin if len(skin) else self.vertices
        return float(np.linalg.norm(skin.max(0) - skin.min(0)))

    def interocular(self) -> float:
        """Distance between the outer eye corners (landmarks 33 and 263) at rest, cm."""
        a, b = landmark_points(self, self.vertices, list(IOD_PAIR))
        return float(np.linalg.norm(a - b))

    def replace(self, **changes) -> FaceRig:
        return dataclasses.replace(self, **changes)

    # ---- persistence ----------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the rig to one .npz file (lossless, atomic)."""
        save_dataclass(self, path, FORMAT)

    @classmethod
    def load(cls, path: str | os.PathLike) -> FaceRig:
        """Read a rig written by :meth:`save`; a bad file raises ``CaptureError``."""
        return load_dataclass(cls, path, FORMAT)


def landmark_support(rig: FaceRig, landmarks=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each tracker landmark sits, as a convex mix of vertices.

    Args:
        landmarks: (K,) landmark ids, or None: all L of them.
    Returns:
        vertex ids (K, 3) int64 (0 where the landmark has none), weights (K, 3) float64
        (barycentric on ``landmark_faces``, else [1, 0, 0] on ``landmark_vertices``), and
        (K,) bool: the landmark has a place on the rig.
    """
    lv = np.asarray(rig.landmark_vertices)
    ids = np.arange(len(lv)) if landmarks is None else np.asarray(landmarks, np.int64)
    have = lv[ids] >= 0
    if rig.landmark_faces is not None and rig.landmark_bary is not None:
        verts = np.asarray(rig.landmark_faces, np.int64)[ids]
        weights = np.asarray(rig.landmark_bary, np.float64)[ids]
        have &= (verts >= 0).all(1)
    else:
        verts = np.repeat(lv[ids, None].astype(np.int64), 3, 1)
        weights = np.broadcast_to(np.array([1.0, 0.0, 0.0]), verts.shape).copy()
    verts = np.where(have[:, None], verts, 0)
    weights = np.where(have[:, None], weights, 0.0)
    return verts, weights, have


def landmark_points(rig: FaceRig, vertices: np.ndarray, landmarks=None) -> np.ndarray:
    """(..., K, 3) the tracker landmarks' points on ``vertices`` (..., V, 3) (the rest
    mesh or any deformed one): barycentric on their triangles where the rig has
    ``landmark_faces``, else their vertices; landmarks without a place are 0.

    Args:
        landmarks: (K,) landmark ids, or None: all L of them.
    """
    verts, weights, _ = landmark_support(rig, landmarks)
    v = np.asarray(vertices)
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    picked = v[..., verts, :]  # (..., K, 3, 3)
    return np.einsum("...kjc,kj->...kc", picked, weights.astype(v.dtype))


def eye_rotation_matrices(eye_rotation: np.ndarray) -> np.ndarray:
    """(..., 2) yaw, pitch in degrees -> (..., 3, 3) rotations R = Ry(yaw) Rx(pitch), in
    head coordinates: yaw > 0 turns the gaze (+z) towards +x (the subject's left), pitch > 0
    tips it down (the Live Link Face convention, :mod:`capture2face.export.livelink`):
    :func:`capture2face.maths.rotations.rotation_ypr` with the pitch negated."""
    a = np.asarray(eye_rotation, np.float64)
    # rotation_ypr's pitch tips +z up; the Live Link one tips it down. No roll.
    return rotation_ypr(np.stack([a[..., 0], -a[..., 1], np.zeros_like(a[..., 0])], -1))


def gaze_directions(eye_rotation: np.ndarray) -> np.ndarray:
    """(..., 2) yaw, pitch in degrees -> (..., 3) unit gaze directions (head coordinates)."""
    return eye_rotation_matrices(eye_rotation)[..., :, 2]


def gaze_angles(direction: np.ndarray) -> np.ndarray:
    """Inverse of :func:`gaze_directions`: (..., 3) directions -> (..., 2) yaw, pitch (deg)."""
    d = np.asarray(direction, np.float64)
    d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    return np.degrees(np.stack([np.arctan2(d[..., 0], d[..., 2]), np.arcsin(np.clip(-d[..., 1], -1, 1))], -1))


def turn_eyes(rig: FaceRig, positions: np.ndarray | None, normals: np.ndarray | None, eye_rotation) -> None:
    """Turn the eyeball vertices of deformed ``positions`` (V, 3) or (F, V, 3) and/or
    ``normals`` (same shape; either may be None) in place by ``eye_rotation`` (2, 2) or
    (F, 2, 2) degrees (yaw, pitch per eye, right then left). A rig without eyes, or
    ``eye_rotation=None``, leaves them as they are."""
    if eye_rotation is None or not rig.has_eyes:
        return
    rot = eye_rotation_matrices(eye_rotation)  # (..., 2, 3, 3)
    for side in (0, 1):
        ids = np.flatnonzero(rig.eye_vertex_side == side)
        rt = np.swapaxes(rot[..., side, :, :], -1, -2)  # row vectors: v @ R^T
        if positions is not None:
            c = np.asarray(rig.eye_centres[side], np.float64)
            positions[..., ids, :] = (positions[..., ids, :] - c) @ rt.astype(positions.dtype) + c
        if normals is not None:
            normals[..., ids, :] = normals[..., ids, :] @ rt.astype(normals.dtype)

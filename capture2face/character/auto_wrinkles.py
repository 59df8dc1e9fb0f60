"""Automatic wrinkle influences on any ARKit character, without a mapping file.

Dutreve et al. 2009 weigh each wrinkle map by how far the face's bones have travelled
towards a reference pose. An ARKit morph character has no face bones, so its own feature
vertices play their part:

1. **Where the face is**: the character's neutral face is rendered from the front and
   tracked with the same MediaPipe tracker as the clips; each landmark is cast onto the
   skin's surface (:mod:`capture2face.character.landmarks`): ``landmark_faces`` and
   ``landmark_bary`` (a point on a triangle), ``landmark_vertices`` (its nearest vertex).
2. **Feature points as bones**: one feature bone per face bone of the default avatar (its
   25 landmarks: brows, lids, cheeks, nose wings, lips, jaw), at the character's surface
   point for that landmark, grouped as the avatar groups its bones. They never translate
   (``Animation.bone_positions`` keep them at rest; the morphs move the face): their
   per-frame positions for the influences are the feature points deformed by the
   morph weights (:func:`capture2face.rig.feature_points.feature_positions`).
3. **Reference poses from the ARKit morphs**: "stretch" = browInnerUp + browOuterUp + eyeWide,
   "compress" = browDown + eyeSquint + noseSneer (all at 1): each feature bone's pose
   position is its surface point under that morph mix.
4. **Masks, regions, zone table** lent by the default avatar fitted to the character's
   landmarks (similarity transform): each face vertex takes the skin weights (as feature
   bones), the region weights of its nearest avatar vertex, and the zone-table rows go by
   ARKit name.

5. **Wrinkle maps and zone masks in the character's own UV space**
   (:func:`capture2face.character.wrinkle_bake.bake_maps`): each texel of a face triangle
   takes the avatar's map at the fitted avatar's surface point nearest the texel's own
   surface point (one continuous field across the character's triangles and UV islands,
   the avatar's fold width scaled to the head), its tangent-space normal turned from the
   avatar's tangent to the character's in the tangent plane (so a flat normal stays flat).
   Maps the character brings (a mapping JSON's) are kept.

The influence view and ``region_influence`` then work as for the default avatar, and the
forehead lines appear where the brows go up.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from capture2face.character.landmark_sources import MORPHS
from capture2face.character.landmarks import pose_weights, with_surface_landmarks
from capture2face.character.wrinkle_bake import bake_maps
from capture2face.errors import CaptureError
from capture2face.maths.rotations import similarity
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig, landmark_points, landmark_support
from capture2face.rig.feature_points import AUTO_PREFIX
from capture2face.topology import IOD_PAIR, N_MESH

log = logging.getLogger("capture2face")

POSES = {
    "stretch": ("browInnerUp", "browOuterUpLeft", "browOuterUpRight", "eyeWideLeft", "eyeWideRight"),
    "compress": ("browDownLeft", "browDownRight", "eyeSquintLeft", "eyeSquintRight", "noseSneerLeft",
                 "noseSneerRight"),
}
# A feature point takes part in a reference pose where it travels at least this share of
# the pose's largest travel (the default avatar's own poses move every bone at least 0.2 of it).
MIN_POSE_SHARE = 0.2
# A face vertex further than this (in inter-ocular distances) from every fitted avatar
# skin vertex is not face (hair, ears, neck): it keeps its own skin and no region.
_FACE_REACH_IOD = 0.08


def _head_skin(rig: FaceRig, points: np.ndarray) -> np.ndarray:
    """(V,) the vertices wrinkles may reach: where the skin has a head joint, those mostly
    on it (not the neck's, the chest's, a collar's); on a face placed from its morphs, also
    only within the front view's hull of its landmarks (``points`` (L, 3)). The avatar fitted
    onto an anime face's landmarks (large eyes, a small mouth) reaches below its chin; on a
    face the tracker read, the fit is within the tracker's error and its reach is kept."""
    out = np.ones(rig.n_vertices, bool) if rig.head_weights is None else np.asarray(rig.head_weights) >= 0.5
    if rig.landmark_source == MORPHS:
        placed = np.flatnonzero(np.asarray(rig.landmark_vertices)[:N_MESH] >= 0)
        out &= Delaunay(points[placed, :2]).find_simplex(rig.vertices[:, :2].astype(np.float64)) >= 0
    return out


def automatic_wrinkles(rig: FaceRig) -> FaceRig:
    """``rig`` (an ARKit morph character without face bones) with feature bones,
    reference poses, influence masks, regions and zone table (see the module docs).

    Raises:
        CaptureError: no face found in its front view, too few ARKit pose morphs, or UVs
            on which the wrinkle maps cannot be baked.
    """
    # The poses' morph mixes: its ARKit morphs, else the presets / Rocketbox morphs they drive.
    pose_names = list(POSES)
    pose_w = np.stack([pose_weights(rig, POSES[p]) for p in pose_names]).astype(np.float32)
    if not pose_w.any():
        raise CaptureError(f"character '{rig.name}': none of the brow / eye / nose morphs that make "
                           "its wrinkle reference poses")
    if rig.landmark_faces is None:  # cast here where the loader has not (a rig built in code)
        rig = with_surface_landmarks(rig)
    lmv = rig.landmark_vertices
    points = landmark_points(rig, rig.vertices).astype(np.float64)  # (L, 3) on the surface
    avatar = default_avatar()
    face_bones = [b for b in range(1, avatar.n_bones) if avatar.bone_landmarks[b] >= 0
                  and lmv[avatar.bone_landmarks[b]] >= 0]
    if len(face_bones) < 4:
        raise CaptureError(f"character '{rig.name}': the tracker found too few of its face's feature points")
    B0 = rig.n_bones
    names = rig.bone_names + [AUTO_PREFIX + avatar.bone_names[b] for b in face_bones]
    feature_lm = avatar.bone_landmarks[face_bones]
    rest = np.concatenate([rig.bone_rest, points[feature_lm]]).astype(np.float32)
    # Reference poses: every feature vertex under the pose's morph mix.
    pose_bones = np.repeat(rest[None], len(pose_names), 0)
    verts, bary, _ = landmark_support(rig, feature_lm)  # (n, 3) each: barycentric on the surface
    travel = np.einsum("pm,mnjc,nj->pnc", pose_w, rig.morph_positions[:, verts], bary)  # (P, n, 3)
    length = np.linalg.norm(travel, axis=-1)
    # A feature the pose barely moves would reach full influence on any small motion (an
    # ICT chin travels 0.06 cm in "compress" and folded at rest): it takes no part.
    travel[length < MIN_POSE_SHARE * length.max(1, keepdims=True)] = 0.0
    pose_bones[:, B0:] += travel
    # Groups: as the avatar groups the same bones; the rig's own joints alone.
    groups = np.concatenate([np.arange(B0), B0 + avatar.bone_groups[face_bones]]).astype(np.int32)
    _, groups = np.unique(groups, return_inverse=True)

    # The avatar fitted onto the character's landmarks lends masks, regions and zones.
    canon = avatar.vertices[avatar.landmark_vertices.clip(0)].astype(np.float64)
    both = np.flatnonzero((avatar.landmark_vertices >= 0) & (lmv >= 0))[:N_MESH]
    both = both[both < N_MESH]
    s, rot, t = similarity(canon[both], points[both])
    fitted = avatar.vertices.astype(np.float64) @ (s * rot).T + t  # (Va, 3) on the character
    askin = np.flatnonzero(avatar.material == 0)
    dist, nearest = cKDTree(fitted[askin]).query(rig.vertices.astype(np.float64), k=1)
    nearest = askin[nearest]
    iod = float(np.linalg.norm(points[IOD_PAIR[0]] - points[IOD_PAIR[1]]))
    face = (rig.material == 0) & (dist < _FACE_REACH_IOD * iod) & _head_skin(rig, points)
    to_rig = np.zeros(avatar.n_bones, np.int64)  # avatar bone -> rig bone (head -> 0)
    to_rig[face_bones] = B0 + np.arange(len(face_bones))
    skin_joints, skin_weights = rig.skin_joints.copy(), rig.skin_weights.copy()
    skin_joints[face] = to_rig[avatar.skin_joints[nearest[face]]]
    skin_weights[face] = avatar.skin_weights[nearest[face]]
    regions = np.zeros((len(avatar.region_names), rig.n_vertices), np.float32)
    regions[:, face] = avatar.region_weights[:, nearest[face]]
    table = rig.zone_table.copy()
    amorph = {n: i for i, n in enumerate(avatar.morph_names)}
    for m, a in arkit_morphs(rig.morph_names).items():
        if a in amorph and not table[m].any():
            table[m] = avatar.zone_table[amorph[a]]
    log.debug("automatic wrinkles: %d feature points, %d face vertices", len(face_bones), int(face.sum()))
    maps = list(rig.wrinkle_map_names)
    wrinkle_maps, zone_masks = bake_maps(rig, avatar, fitted, rot, face)
    return rig.replace(
        wrinkle_maps=wrinkle_maps, zone_masks=zone_masks,
        bone_names=names, bone_rest=rest,
        bone_parents=np.concatenate([rig.bone_parents, np.zeros(len(face_bones), np.int32)]).astype(np.int32),
        bone_landmarks=np.concatenate([rig.bone_landmarks, feature_lm]).astype(np.int32),
        bone_groups=groups.astype(np.int32),
        skin_joints=skin_joints.astype(np.int32), skin_weights=skin_weights.astype(np.float32),
        pose_names=pose_names, pose_bones=pose_bones.astype(np.float32), pose_morph_weights=pose_w,
        pose_maps=np.array([maps.index(p) if p in maps else 0 for p in pose_names], np.int32),
        region_names=list(avatar.region_names), region_weights=regions, zone_table=table,
    )

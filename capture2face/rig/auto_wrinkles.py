"""Automatic wrinkle influences on any ARKit character, without a mapping file.

Dutreve et al. 2009 weigh each wrinkle map by how far the face's bones have travelled
towards a reference pose. An ARKit morph character has no face bones, so its own feature
vertices play their part:

1. **Where the face is**: the character's neutral face is rendered from the front and
   tracked with the same MediaPipe tracker as the clips; each landmark is cast onto the
   surface (the front-most vertex under it): ``landmark_vertices``.
2. **Feature points as bones**: one feature bone per face bone of the default avatar (its
   25 landmarks: brows, lids, cheeks, nose wings, lips, jaw), at the character's vertex
   for that landmark, grouped as the avatar groups its bones. They never translate
   (``Animation.bone_positions`` keep them at rest; the morphs move the face): their
   per-frame positions for the influences are the feature vertices deformed by the
   morph weights (:func:`feature_positions`).
3. **Reference poses from the ARKit morphs**: "stretch" = browInnerUp + browOuterUp + eyeWide,
   "compress" = browDown + eyeSquint + noseSneer (all at 1): each feature bone's pose
   position is its vertex under that morph mix.
4. **Masks, regions, zone table** lent by the default avatar fitted to the character's
   landmarks (similarity transform): each face vertex takes the skin weights (as feature
   bones), the region weights of its nearest avatar vertex, and the zone-table rows go by
   ARKit name.

The influence view and ``region_influence`` then work as for the default avatar. The
wrinkle normal maps themselves stay the character's (flat unless its mapping gives
some): maps baked into the character's own UV space are not made here.
"""

from __future__ import annotations

import logging

import numpy as np

from capture2face.errors import CaptureError
from capture2face.rig.arkit_names import AUTO_PREFIX, arkit_morphs
from capture2face.rig.face_rig import FaceRig

log = logging.getLogger("capture2face")

POSES = {
    "stretch": ("browInnerUp", "browOuterUpLeft", "browOuterUpRight", "eyeWideLeft", "eyeWideRight"),
    "compress": ("browDownLeft", "browDownRight", "eyeSquintLeft", "eyeSquintRight", "noseSneerLeft",
                 "noseSneerRight"),
}
RENDER_SIZE = 512
# A face vertex further than this (in inter-ocular distances) from every fitted avatar
# skin vertex is not face (hair, ears, neck): it keeps its own skin and no region.
_FACE_REACH_IOD = 0.08


def find_landmark_vertices(rig: FaceRig) -> np.ndarray:
    """(478,) int32 vertex under each MediaPipe landmark of the character's neutral face
    rendered from the front (-1 where none).

    Raises:
        CaptureError: the tracker finds no face in the render.
    """
    from scipy.spatial import cKDTree

    from capture2face.render import FrameState, Renderer, RenderOptions
    from capture2face.render.camera import framing_pose, project
    from capture2face.tracking.landmarker import FaceLandmarker, LandmarkerOptions

    opts = RenderOptions(size=RENDER_SIZE, wrinkles="off", samples=4)
    pose = framing_pose(rig, fov_y_degrees=opts.fov_y_degrees)
    with Renderer(rig, opts) as renderer:
        image = renderer.render(FrameState.at_pose(rig, pose))
    with FaceLandmarker.create_from_options(LandmarkerOptions(num_faces=1)) as landmarker:
        obs = landmarker.detect(image, 0.0)
    if obs is None:
        raise CaptureError(f"character '{rig.name}': the tracker finds no face in its front view")
    px = project(rig.vertices, pose, opts.fov_y_degrees, RENDER_SIZE)  # (V, 2)
    depth = -(rig.vertices.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3])[:, 2]
    out = np.full(len(obs.landmarks_px), -1, np.int32)
    lm = obs.landmarks_px.astype(np.float64)
    for material, rows in ((0, slice(0, 468)), (1, slice(468, None))):  # skin; irises on the eyes
        cand = np.flatnonzero((rig.material == material) & np.isfinite(px).all(1))
        if not len(cand):
            continue
        k = min(32, len(cand))
        d, idx = cKDTree(px[cand]).query(lm[rows], k=k)
        d, idx = d.reshape(len(d), k), idx.reshape(len(idx), k)
        # The front-most vertex among those within 2 px (or the nearest, if further): the
        # surface under the landmark, not the back of the head behind it.
        near = d <= np.maximum(d[:, :1], 2.0)
        front = np.where(near, depth[cand][idx], np.inf)
        out[rows] = cand[idx[np.arange(len(idx)), np.argmin(front, axis=1)]]
    return out


def feature_positions(rig: FaceRig, blend_weights: np.ndarray) -> np.ndarray:
    """(F, B, 3) float32 bone positions for the influences: the rest positions, with each
    automatic feature bone at its vertex deformed by the frame's morph weights.

    Args:
        blend_weights: (F, M) morph weights.
    """
    weights = np.asarray(blend_weights, np.float32)
    out = np.repeat(rig.bone_rest[None].astype(np.float32), len(weights), 0)
    auto = [b for b, n in enumerate(rig.bone_names) if n.startswith(AUTO_PREFIX)]
    if not auto:
        return out
    verts = rig.landmark_vertices[rig.bone_landmarks[auto]]
    deltas = rig.morph_positions[:, verts].reshape(rig.n_morphs, -1).astype(np.float32)  # (M, n*3)
    out[:, auto] += (weights @ deltas).reshape(len(weights), len(auto), 3)
    return out


def automatic_wrinkles(rig: FaceRig) -> FaceRig:
    """``rig`` (an ARKit morph character without face bones) with feature bones,
    reference poses, influence masks, regions and zone table (see the module docs).

    Raises:
        CaptureError: no face found in its front view, or too few ARKit pose morphs.
    """
    from scipy.spatial import cKDTree

    from capture2face.gltf.rig_import import _similarity
    from capture2face.rig.avatar import default_avatar

    by_name = {a: m for m, a in arkit_morphs(rig.morph_names).items()}
    if not any(n in by_name for names in POSES.values() for n in names):
        raise CaptureError(f"character '{rig.name}': none of the brow / eye / nose ARKit morphs that make "
                           "its wrinkle reference poses")
    lmv = find_landmark_vertices(rig)
    avatar = default_avatar()
    face_bones = [b for b in range(1, avatar.n_bones) if avatar.bone_landmarks[b] >= 0
                  and lmv[avatar.bone_landmarks[b]] >= 0]
    if len(face_bones) < 4:
        raise CaptureError(f"character '{rig.name}': the tracker found too few of its face's feature points")
    B0 = rig.n_bones
    names = rig.bone_names + [AUTO_PREFIX + avatar.bone_names[b] for b in face_bones]
    feature_lm = avatar.bone_landmarks[face_bones]
    feature_v = lmv[feature_lm]
    rest = np.concatenate([rig.bone_rest, rig.vertices[feature_v]]).astype(np.float32)
    B = len(names)
    # Reference poses: every feature vertex under the pose's morph mix.
    pose_names = list(POSES)
    pose_w = np.zeros((len(pose_names), rig.n_morphs), np.float32)
    for p, pname in enumerate(pose_names):
        for n in POSES[pname]:
            if n in by_name:
                pose_w[p, by_name[n]] = 1.0
    pose_bones = np.repeat(rest[None], len(pose_names), 0)
    pose_bones[:, B0:] += np.einsum("pm,mnc->pnc", pose_w, rig.morph_positions[:, feature_v])
    # Groups: as the avatar groups the same bones; the rig's own joints alone.
    groups = np.concatenate([np.arange(B0), B0 + avatar.bone_groups[face_bones]]).astype(np.int32)
    _, groups = np.unique(groups, return_inverse=True)

    # The avatar fitted onto the character's landmarks lends masks, regions and zones.
    canon = avatar.vertices[avatar.landmark_vertices.clip(0)].astype(np.float64)
    both = np.flatnonzero((avatar.landmark_vertices >= 0) & (lmv >= 0))[:468]
    both = both[both < 468]
    s, rot, t = _similarity(canon[both], rig.vertices[lmv[both]].astype(np.float64))
    fitted = avatar.vertices.astype(np.float64) @ (s * rot).T + t  # (Va, 3) on the character
    askin = np.flatnonzero(avatar.material == 0)
    dist, nearest = cKDTree(fitted[askin]).query(rig.vertices.astype(np.float64), k=1)
    nearest = askin[nearest]
    iod = float(np.linalg.norm(rig.vertices[lmv[33]] - rig.vertices[lmv[263]]))
    face = (rig.material == 0) & (dist < _FACE_REACH_IOD * iod)
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
    return rig.replace(
        landmark_vertices=lmv,
        bone_names=names, bone_rest=rest,
        bone_parents=np.concatenate([rig.bone_parents, np.zeros(len(face_bones), np.int32)]).astype(np.int32),
        bone_landmarks=np.concatenate([rig.bone_landmarks, feature_lm]).astype(np.int32),
        bone_groups=groups.astype(np.int32),
        skin_joints=skin_joints.astype(np.int32), skin_weights=skin_weights.astype(np.float32),
        pose_names=pose_names, pose_bones=pose_bones.astype(np.float32), pose_morph_weights=pose_w,
        pose_maps=np.array([maps.index(p) if p in maps else 0 for p in pose_names], np.int32),
        region_names=list(avatar.region_names), region_weights=regions, zone_table=table,
    )

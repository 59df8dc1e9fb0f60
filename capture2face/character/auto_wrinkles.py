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

5. **Wrinkle maps and zone masks in the character's own UV space** (:func:`_bake_maps`):
   each texel of a face triangle takes the avatar's map at the avatar UV of the
   triangle's vertices (each vertex's nearest fitted avatar vertex, interpolated), its
   tangent-space normal turned from the avatar's tangent to the character's in the
   tangent plane (so a flat normal stays flat).
   Maps the character brings (a mapping JSON's) are kept.

The influence view and ``region_influence`` then work as for the default avatar, and the
forehead lines appear where the brows go up.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from capture2face.character.landmarks import pose_weights, with_surface_landmarks
from capture2face.errors import CaptureError
from capture2face.maths.rotations import similarity
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig, landmark_points, landmark_support
from capture2face.rig.feature_points import AUTO_PREFIX
from capture2face.rig.maps import decode_normals, encode_normals
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
    wrinkle_maps, zone_masks = _bake_maps(rig, avatar, nearest, face)
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


def _bake_maps(rig: FaceRig, avatar: FaceRig, nearest: np.ndarray, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The avatar's "stretch" / "compress" wrinkle maps and zone masks baked into the
    character's UV space over its face triangles (flat normals, zero zones elsewhere).

    Args:
        nearest: (V,) the nearest fitted avatar vertex of each character vertex.
        face: (V,) bool, the character's face vertices.
    Returns:
        wrinkle maps (K, H, W, 3) in ``rig.wrinkle_map_names`` order, zone masks (H, W, 8).
    Raises:
        CaptureError: the face triangles cover no texel (nothing to bake into).
    """
    import cv2

    H, W = rig.albedo.shape[:2]
    flat = np.array([128, 128, 255], np.uint8)
    maps = rig.wrinkle_maps.copy()
    zones = rig.zone_masks.copy()
    todo = [k for k, n in enumerate(rig.wrinkle_map_names)
            if n in avatar.wrinkle_map_names and (maps[k] == flat).all()]  # keep maps the character brings
    bake_zones = not zones.any()
    tris = rig.triangles[face[rig.triangles].all(1)]
    # A triangle whose vertices' avatar UVs lie far apart straddles one of the avatar's UV
    # seams (lips, lids: vertices at one position with two UVs): left flat.
    askin = avatar.triangles[(avatar.material[avatar.triangles] == 0).all(1)]
    limit = 2.0 * np.percentile(_uv_spread(avatar.uvs[askin]), 99)
    tris = tris[_uv_spread(avatar.uvs[nearest[tris]]) <= limit]
    if not len(tris) or not (todo or bake_zones):
        return maps, zones
    ys, xs, ids = _texels(rig, tris, H, W)
    tri = tris[ids[ys, xs]]  # (N, 3)
    p = np.stack([(xs + 0.5) / W, (ys + 0.5) / H], 1)
    a, b, c = (rig.uvs[tri[:, i]].astype(np.float64) for i in range(3))
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    l1 = np.clip((v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den, 0, 1)
    l2 = np.clip((v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den, 0, 1)
    bary = np.stack([1 - l1 - l2, l1, l2], 1)  # (N, 3)
    auv = np.einsum("nk,nkc->nc", bary, avatar.uvs[nearest[tri]].astype(np.float64))
    ah, aw = avatar.wrinkle_maps.shape[1:3]
    # remap takes maps under 32767 px a side: the N lookups as rows of 1024.
    n_rows = -(-len(p) // 1024)
    mx = np.zeros(n_rows * 1024, np.float32)
    my = np.zeros(n_rows * 1024, np.float32)
    mx[: len(p)], my[: len(p)] = auv[:, 0] * aw - 0.5, auv[:, 1] * ah - 0.5
    mx, my = mx.reshape(n_rows, 1024), my.reshape(n_rows, 1024)

    def sample(image: np.ndarray) -> np.ndarray:  # (N, C) bilinear at the avatar UVs
        out = cv2.remap(np.ascontiguousarray(image), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(n_rows * 1024, -1)[: len(p)]

    if todo:
        # Per vertex, the turn in the tangent plane from the avatar's tangent to the
        # character's (and a mirror where their bitangents disagree), interpolated: flat
        # stays flat wherever the two surfaces' normals differ.
        tc, nc = rig.tangents[:, :3].astype(np.float64), rig.normals.astype(np.float64)
        bc = rig.tangents[:, 3:4] * np.cross(nc, tc)
        ta = avatar.tangents[nearest, :3].astype(np.float64)
        ta = ta - np.einsum("vc,vc->v", ta, nc)[:, None] * nc
        cos_sin = np.stack([np.einsum("vc,vc->v", ta, tc), np.einsum("vc,vc->v", ta, bc)], 1)
        cos_sin /= np.maximum(np.linalg.norm(cos_sin, axis=1, keepdims=True), 1e-12)
        mirror = np.where(avatar.tangents[nearest, 3] * rig.tangents[:, 3] < 0, -1.0, 1.0)
        cs = np.einsum("nk,nkc->nc", bary, cos_sin[tri])
        cs /= np.maximum(np.linalg.norm(cs, axis=1, keepdims=True), 1e-12)
        m = np.einsum("nk,nk->n", bary, mirror[tri])
        for k in todo:
            src = avatar.wrinkle_maps[avatar.wrinkle_map_names.index(rig.wrinkle_map_names[k])]
            n = decode_normals(sample(src))
            x, y = n[:, 0], n[:, 1] * np.where(m < 0, -1.0, 1.0)
            # A turn in the tangent plane: unit normals stay unit.
            maps[k, ys, xs] = encode_normals(
                np.stack([cs[:, 0] * x - cs[:, 1] * y, cs[:, 1] * x + cs[:, 0] * y, n[:, 2]], 1))
    if bake_zones:
        zones[ys, xs, :4] = sample(avatar.zone_masks[..., :4])
        zones[ys, xs, 4:8] = sample(avatar.zone_masks[..., 4:8])
    return maps, zones


def _texels(rig: FaceRig, tris: np.ndarray, H: int, W: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texels (rows, columns) the triangles ``tris`` cover in UV space and the (H, W)
    triangle id of each texel (-1: none).

    Raises:
        CaptureError: they cover none (no UVs, all in one point, or outside 0-1): there is
            nowhere to bake the maps, and a wrinkle without its map is nothing.
    """
    import cv2

    # Texel centres at +0.5; 4 fractional bits.
    ids = np.full((H, W), -1, np.int32)
    corners = np.rint((rig.uvs[tris] * [W, H] - 0.5) * 16).astype(np.int32)  # (T, 3, 2)
    for t in range(len(tris)):  # per triangle: OpenCV fills one polygon a call
        cv2.fillConvexPoly(ids, corners[t], int(t), lineType=cv2.LINE_8, shift=4)
    ys, xs = np.nonzero(ids >= 0)
    if not len(ys):
        raise CaptureError(f"character '{rig.name}': its face's UVs cover no texel of its texture "
                           "(no TEXCOORD_0, or UVs outside 0-1): no wrinkle maps to bake")
    return ys, xs, ids


def _uv_spread(uv: np.ndarray) -> np.ndarray:
    """(T, 3, 2) triangle UVs -> (T,) longest edge."""
    return np.linalg.norm(uv - np.roll(uv, 1, axis=1), axis=2).max(1)

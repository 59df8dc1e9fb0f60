"""What the default avatar lends a user's character that ties bones to tracker landmarks:
the avatar fitted to those bones (similarity transform of its landmarks onto the bones'
rest positions) gives reference poses (its bone offsets for the same landmarks, scaled by
face size), zone table rows (by morph name), region weights and tracker landmark vertices
(nearest vertices to its fitted landmarks), where the mapping JSON does not give them.

Without bones tied to landmarks nothing is lent: an ARKit morph character is driven by
the clip's ARKit curves (:func:`capture2face.rig.arkit_names.drive_mode`); a character
with tracker landmark vertices from its mapping gets a warning that nothing was lent.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial import cKDTree

from capture2face.gltf.mapped_rig import posed_names, zone_table_names
from capture2face.gltf.mapping import Mapping
from capture2face.maths.rotations import similarity
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig


def lend_from_avatar(rig: FaceRig, mapping: Mapping) -> FaceRig:
    """``rig`` (imported with ``mapping``) with what the default avatar lends it (the module docs)."""
    known = np.flatnonzero(rig.bone_landmarks >= 0)
    if len(known) < 3:
        if arkit_morphs(rig.morph_names) or not (rig.landmark_vertices >= 0).any():
            # An ARKit morph character (the ARKit curves drive it: nothing to lend), or
            # one nothing can drive, which the check before tracking says in one line.
            return rig
        warnings.warn(f"character '{rig.name}': fewer than 3 bones tied to tracker landmarks; "
                      "no default poses, regions or landmark vertices", stacklevel=3)
        return rig
    avatar = default_avatar()
    canon = avatar.vertices[avatar.landmark_vertices.clip(0)].astype(np.float64)  # (L, 3)
    canon[avatar.landmark_vertices < 0] = np.nan
    ok = [b for b in known if np.isfinite(canon[rig.bone_landmarks[b]]).all()]
    if len(ok) < 3:
        return rig
    s, rot, t = similarity(canon[rig.bone_landmarks[ok]], rig.bone_rest[ok].astype(np.float64))
    fitted = canon @ (s * rot).T + t  # avatar landmarks on the character
    rig = rig.replace(pose_bones=_lent_poses(rig, avatar, known, s * rot, posed_names(mapping)),
                      zone_table=_lent_zone_table(rig, avatar, zone_table_names(mapping)))
    return _lent_regions(rig, avatar, fitted)


def _lent_poses(rig: FaceRig, avatar: FaceRig, known: np.ndarray, turn: np.ndarray, posed: set[str]) -> np.ndarray:
    """(P, B, 3) pose bones: the avatar's offsets of the bone on the same landmark, turned
    and scaled by ``turn`` (3, 3), for the poses the mapping leaves without motion."""
    lm_pos = {}
    for b in range(1, avatar.n_bones):
        if avatar.bone_landmarks[b] >= 0:
            lm_pos[int(avatar.bone_landmarks[b])] = b
    pose_bones = rig.pose_bones.copy()
    for p, pname in enumerate(rig.pose_names):
        if pname in posed or pname not in avatar.pose_names:
            continue
        ap = avatar.pose_index(pname)
        for b in known:
            ab = lm_pos.get(int(rig.bone_landmarks[b]))
            if ab is not None:
                off = avatar.pose_bones[ap, ab] - avatar.bone_rest[ab]
                pose_bones[p, b] = rig.bone_rest[b] + (turn @ off).astype(np.float32)
    return pose_bones


def _lent_zone_table(rig: FaceRig, avatar: FaceRig, tabled: set[str]) -> np.ndarray:
    """(M, 8) zone table: the avatar's rows by (case-insensitive) morph name where the mapping gives none."""
    amorph = {n.lower(): i for i, n in enumerate(avatar.morph_names)}
    table = rig.zone_table.copy()
    for i, n in enumerate(rig.morph_names):
        if n.lower() not in tabled and n.lower() in amorph:
            table[i] = avatar.zone_table[amorph[n.lower()]]
    return table


def _lent_regions(rig: FaceRig, avatar: FaceRig, fitted: np.ndarray) -> FaceRig:
    """Regions and landmark vertices: nearest fitted avatar landmark (``fitted`` (L, 3)) /
    nearest skin vertex."""
    valid = np.flatnonzero(np.isfinite(fitted).all(1))
    skin = np.flatnonzero(rig.material == 0)
    regions = rig.region_weights
    lmv = rig.landmark_vertices.copy()
    if len(skin):
        tree = cKDTree(fitted[valid])
        _, nearest = tree.query(rig.vertices.astype(np.float64), k=1)
        areg = avatar.region_weights[:, avatar.landmark_vertices[valid]]  # (R, n valid)
        regions = np.zeros_like(rig.region_weights)
        for ri, rname in enumerate(rig.region_names):
            if rname in avatar.region_names:
                regions[ri, skin] = areg[avatar.region_names.index(rname), nearest[skin]]
        _, vidx = cKDTree(rig.vertices[skin]).query(fitted[valid], k=1)
        fill = lmv[valid] < 0
        lmv[valid[fill]] = skin[vidx[fill]]
    return rig.replace(region_weights=regions.astype(np.float32), landmark_vertices=lmv.astype(np.int32))

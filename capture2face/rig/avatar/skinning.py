"""The default avatar's skinning: geodesic falloffs of the face bones over the skin, then
every other part's joints and weights from the skin's."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra

from capture2face.rig import features
from capture2face.rig.avatar.bones import BONES, FOREHEAD_PIN_CM, FOREHEAD_PIN_HEAD, BoneSpec
from capture2face.rig.avatar.landmarks import BROW_R
from capture2face.rig.avatar.layout import Head, Mouth, Teeth


def skin_weights(skin: np.ndarray, graph, loops: list[np.ndarray], lowerness: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic compact-support falloffs, head takes the remainder, top 4 kept. The jaw's
    falloff is broad (the whole lower face follows it) and gated by ``lowerness`` (n_skin,)
    so it never reaches the upper lip.

    Args:
        skin: (n_skin, 3) skin vertex positions; graph: their edge-length graph;
        loops: the skin's boundary loops.
    Returns (joints (n_skin, 4), weights (n_skin, 4))."""
    n_skin = len(skin)
    dist = np.empty((len(BONES) - 1, n_skin))
    for i, b in enumerate(BONES[1:]):
        dist[i] = dijkstra(graph, indices=_bone_source(skin, b), directed=False, min_only=True)
    radius = np.array([b.radius for b in BONES[1:]])[:, None]
    r = np.clip(dist / radius, 0.0, 1.0)
    k = (1.0 - r**2) ** 3  # smooth, 1 on the bone's source, 0 at and beyond the radius
    k[[b.name for b in BONES[1:]].index("jaw")] *= lowerness
    # The hairline stays partly with the head, so a brow raise bunches the forehead's
    # skin below it instead of lifting the face's whole top edge.
    outer = max(loops, key=len)
    top = outer[skin[outer, 1] > skin[list(BROW_R), 1].max()]
    to_top = dijkstra(graph, indices=top, directed=False, min_only=True)
    pin = 1.0 - FOREHEAD_PIN_HEAD * (1.0 - features.smoothstep(to_top / FOREHEAD_PIN_CM))
    k[[i for i, b in enumerate(BONES[1:]) if b.name.startswith("brow")]] *= pin
    total = k.sum(0)
    dense = np.zeros((n_skin, len(BONES)))
    dense[:, 1:] = (k / np.maximum(total, 1.0)).T
    dense[:, 0] = np.maximum(0.0, 1.0 - total)
    return top4(dense)


def _bone_source(skin: np.ndarray, bone: BoneSpec) -> np.ndarray:
    """Vertices at full weight: the landmark, plus the skin within 0.4 cm (seen from the
    front) of each ``reach`` segment and no farther from the landmark than its end."""
    d = skin - skin[bone.landmark]
    medial = -np.sign(skin[bone.landmark, 0])  # +x for the subject's right side
    source = {bone.landmark}
    for along_x, along_y in bone.reach:
        end = np.array([medial * along_x, along_y])
        t = np.clip(d[:, :2] @ end / (end @ end), 0.0, 1.0)
        near = np.linalg.norm(d[:, :2] - t[:, None] * end, axis=1) < 0.4
        source |= set(np.flatnonzero(near & (np.linalg.norm(d, axis=1) <= np.hypot(*end))).tolist())
    return np.array(sorted(source))


def top4(dense: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(-dense, axis=1, kind="stable")[:, :4]
    w = np.take_along_axis(dense, order, axis=1)
    w = w / w.sum(1, keepdims=True)
    joints = np.where(w > 0, order, 0).astype(np.int32)
    return joints, w.astype(np.float32)


def part_skinning(joints: np.ndarray, weights: np.ndarray, mouth: Mouth, teeth: Teeth, head: Head,
                   n_ears: int) -> tuple[np.ndarray, np.ndarray]:
    """(joints (V, 4) int32, weights (V, 4) float32) of every vertex from the skin's
    ``joints`` and ``weights`` (n_skin, 4).

    Skinning of the extra parts: eyes ride the head; the mouth interior copies the
    contour vertex it hangs from (the cap takes the mean of the last ring)."""
    n_eye = mouth.start - len(joints)
    m_joints, m_weights = joints[mouth.src].copy(), weights[mouth.src].copy()
    cap_dense = np.zeros((1, len(BONES)))
    last_ring = mouth.last_ring
    np.add.at(cap_dense[0], joints[last_ring].ravel(), weights[last_ring].ravel() / len(last_ring))
    cj, cw = top4(cap_dense)
    m_joints[mouth.source < 0], m_weights[mouth.source < 0] = cj, cw
    # The upper teeth ride the head, the lower ones and the tongue the jaw.
    jaw = [b.name for b in BONES].index("jaw")
    n_teeth = len(teeth.verts)
    t_joints = np.zeros((n_teeth, 4), np.int32)
    t_joints[teeth.part > 0, 0] = jaw
    h_joints, h_weights = _head_skinning(joints, weights, head)
    all_joints = np.vstack([joints, np.zeros((n_eye, 4), np.int32), m_joints, t_joints, h_joints,
                            np.zeros((n_ears, 4), np.int32)]).astype(np.int32)
    eye_w = np.zeros((n_eye + n_teeth + n_ears, 4), np.float32)
    eye_w[:, 0] = 1.0
    all_weights = np.vstack([weights, eye_w[:n_eye], m_weights, eye_w[n_eye:n_eye + n_teeth], h_weights,
                             eye_w[n_eye + n_teeth:]]).astype(np.float32)
    return all_joints, all_weights


def _head_skinning(joints: np.ndarray, weights: np.ndarray, head: Head) -> tuple[np.ndarray, np.ndarray]:
    """(joints, weights) (H, 4) of the head shell."""
    hv, head_src, follow = head.verts, head.src, head.follow
    # The head's first rings take the face edge's skinning, fading to the head bone.
    h_dense = np.zeros((len(hv), len(BONES)))
    np.add.at(h_dense, (np.repeat(np.arange(len(hv)), 4), joints[head_src].ravel()),
              (follow * weights[head_src]).ravel())
    h_dense[:, 0] += 1.0 - follow[:, 0]
    return top4(h_dense)

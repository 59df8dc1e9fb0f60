"""Skins: the skeleton (the drawn meshes' joints united, the head joint as bone 0), each
mesh's mesh -> scene transform at its bind pose, and the skin weights as FaceRig bones."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import GlbReader
from capture2face.gltf.scene import parents

_NOT_HEAD = ("top", "end", "nub", "tip", "eye", "jaw", "hair")


@dataclass(frozen=True)
class Skeleton:
    """FaceRig bones of a file (B bones, J joints united over the drawn meshes' skins).

    bone_names (B,) with bone 0 ``head``, bone_rest (B, 3) bind-pose positions in glTF
    units (scene space), bone_parents (B,), joint_to_bone (max(J, 1),) bone of each united
    joint, node_joint_map: skinned mesh node -> (its skin's joints,) united joint index,
    node_to_scene: drawn mesh node -> (4, 4) mesh -> scene transform, head_subtree (B,)
    bones a head rotation turns, whether bone 0 is a joint of the file, J, and bone_nodes
    (B,) the node of each bone (-1: a synthetic head).
    """

    bone_names: list[str]
    bone_rest: np.ndarray
    bone_parents: np.ndarray
    joint_to_bone: np.ndarray
    node_joint_map: dict[int, np.ndarray]
    node_to_scene: dict[int, np.ndarray]
    has_head_joint: bool
    head_subtree: np.ndarray
    n_joints: int
    bone_nodes: np.ndarray


def find_head(joint_names: list[str], head_bone: str | None = None) -> int | None:
    """The skin joint that becomes bone 0 ``head``: ``head_bone`` (the mapping's), else a
    joint called head (any case, any prefix such as ``mixamorig:Head``), else the neck."""
    if head_bone is not None:
        if head_bone not in joint_names:
            raise CaptureError(f"mapping: head_bone '{head_bone}' is not a joint of the skin")
        return joint_names.index(head_bone)
    bare = [n.lower().rsplit(":", 1)[-1].rsplit("|", 1)[-1] for n in joint_names]
    for want in ("head", "neck"):
        exact = [k for k, n in enumerate(bare) if n == want]
        if exact:
            return exact[0]
        loose = [k for k, n in enumerate(bare) if want in n and not any(w in n for w in _NOT_HEAD)]
        if loose:
            return loose[0]
    return None


def _united_joints(r: GlbReader, picked: list[int], world: list[np.ndarray]
                   ) -> tuple[list[int], dict[int, np.ndarray], dict[int, np.ndarray], dict[int, np.ndarray]]:
    """The drawn meshes' skin joints united by node: (joint nodes, joint node -> bind-pose
    world matrix, mesh node -> its skin's joint k -> united index, mesh node -> scene)."""
    g = r.gltf
    nodes = g.get("nodes", [])
    joints: list[int] = []
    bind: dict[int, np.ndarray] = {}
    node_joint_map: dict[int, np.ndarray] = {}
    node_to_scene: dict[int, np.ndarray] = {}
    for ni in picked:
        node = nodes[ni]
        if "skin" not in node:
            node_to_scene[ni] = world[ni]
            continue
        skin = g["skins"][node["skin"]]
        sj = [int(j) for j in skin["joints"]]
        if "inverseBindMatrices" in skin:
            ibm = r.accessor(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1).astype(np.float64)
        else:
            ibm = np.tile(np.eye(4), (len(sj), 1, 1))
        # Bind-pose space: skinned vertices render at joint_world @ IBM @ v. The first
        # joint's product is the mesh -> scene transform (identity for our own exports).
        to_scene = world[sj[0]] @ ibm[0] if sj else world[ni]
        if np.allclose(to_scene, np.eye(4), atol=1e-7):
            to_scene = np.eye(4)
        node_to_scene[ni] = to_scene
        remap = np.zeros(max(len(sj), 1), np.int64)
        for k, j in enumerate(sj):
            if j not in bind:
                bind[j] = to_scene @ np.linalg.inv(ibm[k])
                joints.append(j)
            remap[k] = joints.index(j)
        node_joint_map[ni] = remap
    return joints, bind, node_joint_map, node_to_scene


def read_skeleton(r: GlbReader, picked: list[int], world: list[np.ndarray], head_bone: str | None) -> Skeleton:
    """FaceRig bones = head + every joint of the drawn meshes' skins (their union, by
    node), rest positions at the bind pose (glTF units, scene space), parents, and the
    head's subtree (the joints a head rotation turns)."""
    nodes = r.gltf.get("nodes", [])
    joints, bind, node_joint_map, node_to_scene = _united_joints(r, picked, world)
    joint_names = [str(nodes[j].get("name", f"joint_{k}")) for k, j in enumerate(joints)]
    head_k = find_head(joint_names, head_bone) if joints else None
    if head_k is None and head_bone is not None:
        raise CaptureError(f"mapping: head_bone '{head_bone}' is not a joint of the skin")
    # bone b <- united joint order[b] (None = a synthetic head)
    order = ([head_k] if head_k is not None else [None]) + [k for k in range(len(joints)) if k != head_k]
    bone_names = ["head"] + [joint_names[k] for k in order[1:]]
    B = len(bone_names)
    joint_to_bone = np.zeros(max(len(joints), 1), np.int64)
    for b, k in enumerate(order):
        if k is not None:
            joint_to_bone[k] = b
    bone_rest = np.zeros((B, 3))
    for b, k in enumerate(order):
        if k is not None:
            bone_rest[b] = bind[joints[k]][:3, 3]
    parent_of = parents(nodes)
    joint_set = {j: k for k, j in enumerate(joints)}
    bone_parents = np.full(B, -1, np.int32)
    for b, k in enumerate(order[1:], start=1):
        n_ = parent_of.get(joints[k])
        while n_ is not None and n_ not in joint_set:
            n_ = parent_of.get(n_)
        bone_parents[b] = joint_to_bone[joint_set[n_]] if n_ is not None else 0
        if bone_parents[b] == b:
            bone_parents[b] = 0
    # The head's subtree in the file's hierarchy (bone_parents hangs every root on bone 0,
    # the body's too, so it cannot tell).
    head_subtree = np.zeros(B, bool)
    if head_k is not None:
        head_node = joints[head_k]
        for b, k in enumerate(order):
            n_ = joints[k] if k is not None else None
            while n_ is not None and n_ != head_node:
                n_ = parent_of.get(n_)
            head_subtree[b] = n_ is not None
    return Skeleton(bone_names=bone_names, bone_rest=bone_rest, bone_parents=bone_parents,
                    joint_to_bone=joint_to_bone, node_joint_map=node_joint_map, node_to_scene=node_to_scene,
                    has_head_joint=head_k is not None, head_subtree=head_subtree, n_joints=len(joints),
                    bone_nodes=np.array([joints[k] if k is not None else -1 for k in order], np.int64))


def skin_weights(n_vertices: int, parts: list[tuple[slice, np.ndarray | None, np.ndarray | None]]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(V, 4) bones and convex weights: the 4 largest influences, renormalized; vertices
    of unskinned meshes (and weightless ones) hang on bone 0. ``parts``: per drawn mesh
    (its rows, its (n, J) bones or None, its (n, J) weights)."""
    skin_joints = np.zeros((n_vertices, 4), np.int32)
    weights_out = np.zeros((n_vertices, 4), np.float32)
    weights_out[:, 0] = 1.0
    for rows, bones, weights in parts:
        if bones is None:
            continue
        jb = bones
        w = np.clip(np.nan_to_num(weights.astype(np.float32)), 0.0, None)
        # The 4 largest influences, in their original slot order.
        keep = np.sort(np.argsort(-w, axis=1, kind="stable")[:, :4], axis=1)
        jb = np.take_along_axis(jb, keep, 1)
        w = np.take_along_axis(w, keep, 1)
        if w.shape[1] < 4:
            jb = np.pad(jb, ((0, 0), (0, 4 - w.shape[1])))
            w = np.pad(w, ((0, 0), (0, 4 - w.shape[1])))
        total = w.sum(1, dtype=np.float64)
        empty = total <= 0
        renorm = ~empty & (np.abs(total - 1.0) > 1e-6)
        w[renorm] = (w[renorm] / total[renorm, None]).astype(np.float32)
        w[empty] = [1, 0, 0, 0]
        jb[empty] = 0
        jb[w <= 0] = 0
        skin_joints[rows], weights_out[rows] = jb, w
    return skin_joints, weights_out


def head_weights(skin_joints: np.ndarray, weights: np.ndarray, skeleton: Skeleton) -> np.ndarray | None:
    """(V,) how much of the head rotation each vertex takes: its skin weights (V, 4) on the
    head joint and the joints below it (eyes, jaw); None without a head joint (the whole
    character turns)."""
    if not skeleton.has_head_joint or skeleton.n_joints < 2:
        return None
    return (weights * skeleton.head_subtree[skin_joints]).sum(1).astype(np.float32)

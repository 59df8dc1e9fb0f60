"""``animation.glb``: the character with skin, morph targets and the performance.

One glTF animation, sampled once per frame with LINEAR interpolation, all samplers sharing
one time accessor (seconds from the first frame):

* per bone, a ``translation`` channel on its joint node: the bone's position relative to
  its parent bone (metres; bones translate only, so this is all a joint does);
* one ``weights`` channel on the mesh node: F x M morph weights in [0, 1] in the order of
  ``mesh.extras.targetNames``;
* a ``rotation`` channel on the skeleton root node ``capture2face_root``: the head's
  rotation from the track's head pose (rotation only, so the face turns in place);
* a ``rotation`` channel on each eye joint (``eye_R``, ``eye_L``) when the rig has them
  and the animation has a gaze: ``Animation.eye_rotation`` as Ry(yaw) Rx(pitch).

glTF has no frame rate: the animation's ``extras`` carry ``{"fps": ..., "frames": F}``.

:func:`read_glb_animation` reads such an animation back (tests, tools);
:func:`read_animation_keyframe_count` is what the end-to-end check uses.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import METRES_PER_CM, GlbBuilder, GlbReader

# rotation_part and head_rotations lived here; importable from here still.
from capture2face.maths.rotations import head_rotations, rotation_part  # noqa: F401
from capture2face.rig.face_rig import eye_rotation_matrices


def frame_times(animation, fps: float | None) -> np.ndarray:
    """(F,) float32 seconds from the first frame, strictly increasing as glTF requires.

    With ``fps`` (or when the clip's timestamps do not increase strictly once rounded to
    float32) the times are frame / fps.
    """
    n = animation.n_frames
    if fps is None:
        t = (np.asarray(animation.times, np.float64) - float(animation.times[0])).astype(np.float32)
        if n < 2 or np.all(np.diff(t) > 0):
            return t
        fps = animation.fps
    if not fps or fps <= 0 or not np.isfinite(fps):
        raise CaptureError("animation timestamps do not increase and its frame rate is unknown; pass fps=")
    return (np.arange(n, dtype=np.float64) / float(fps)).astype(np.float32)


def add_animation(builder: GlbBuilder, rig, animation, nodes: dict, fps: float | None = None,
                  head_rotation: bool = True, name: str = "performance") -> int:
    """Append the glTF animation of ``animation`` (on ``rig``) to ``builder``.

    ``nodes`` is what :func:`capture2face.gltf.build_rig_gltf` returns. Bones and
    morphs are matched by name: a rig bone the animation lacks stays at rest, a morph it
    lacks stays at 0. Returns the animation index.
    """
    F = animation.n_frames
    if F == 0:
        raise CaptureError("the animation has no frames; nothing to export")
    times = frame_times(animation, fps)
    samplers: list[dict] = []
    channels: list[dict] = []
    t_acc = builder.accessor(times, minmax=True)

    def channel(output: int, node: int, path: str) -> None:
        samplers.append({"input": t_acc, "output": output, "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    # Bone translations, parent-relative, metres.
    src = {n: i for i, n in enumerate(animation.bone_names)}
    have = [i for i, n in enumerate(rig.bone_names) if n in src]
    parents = rig.bone_parents.astype(np.int64)
    rel32 = np.empty((F, rig.n_bones, 3), np.float32)
    for s in range(0, F, 4096):  # float64 temporaries a block of frames at a time
        pos = np.repeat(rig.bone_rest.astype(np.float64)[None], min(F - s, 4096), axis=0)
        pos[:, have] = np.asarray(animation.bone_positions[s:s + 4096], np.float64)[
            :, [src[rig.bone_names[i]] for i in have]]
        rel = pos - np.where(parents[None, :, None] >= 0, pos[:, np.maximum(parents, 0)], 0.0)
        rel32[s:s + 4096] = rel * METRES_PER_CM
    for i, node in enumerate(nodes["joints"]):
        channel(builder.accessor(np.ascontiguousarray(rel32[:, i])), node, "translation")

    # Morph weights, F x M scalars in the mesh's target order.
    if rig.n_morphs:
        srcm = {n: i for i, n in enumerate(animation.blend_names)}
        w = np.zeros((F, rig.n_morphs), np.float32)
        for m, n in enumerate(rig.morph_names):
            if n in srcm:
                w[:, m] = animation.blend_weights[:, srcm[n]]
        w = np.clip(np.nan_to_num(w), 0.0, 1.0).astype(np.float32)
        channel(builder.accessor(w.reshape(-1)), nodes["mesh"], "weights")

    if head_rotation and animation.head_pose is not None and len(animation.head_pose) == F:
        q = head_rotations(animation.head_pose).astype(np.float32)
        channel(builder.accessor(q), nodes["root"], "rotation")

    gaze = getattr(animation, "eye_rotation", None)
    if nodes.get("eyes") and gaze is not None and len(gaze) == F:
        rot = eye_rotation_matrices(np.nan_to_num(np.asarray(gaze, np.float64)))  # (F, 2, 3, 3)
        for side, node in enumerate(nodes["eyes"]):
            channel(builder.accessor(head_rotations(rot[:, side]).astype(np.float32)), node, "rotation")

    # glTF keeps seconds, not frames: the rate goes along for tools that need one (Blender).
    extras = {"fps": float(fps or animation.fps), "frames": int(F)}
    return builder.add("animations", {"name": name, "samplers": samplers, "channels": channels, "extras": extras})


@dataclass
class GlbAnimation:
    """An animation read back from a .glb. F keyframes, B joints, M morph targets.

    Attributes:
        times: (F,) float32 seconds.
        joint_names: B names of the skin's joints.
        bone_positions: (F, B, 3) float64 joint positions (cm) under the skeleton root,
            i.e. in head coordinates, composed from the parent-relative translations.
        target_names: M morph names (``mesh.extras.targetNames``).
        weights: (F, M) float32 morph weights, or None.
        root_rotation: (F, 4) float32 quaternions (x, y, z, w) of the root, or None.
        eye_rotation: (F, 2, 4) float32 quaternions of the eye joints (right, left), or None.
    """

    times: np.ndarray
    joint_names: list[str]
    bone_positions: np.ndarray
    target_names: list[str]
    weights: np.ndarray | None
    root_rotation: np.ndarray | None
    eye_rotation: np.ndarray | None = None


def read_glb_animation(path: str | os.PathLike, index: int = 0, cm_per_unit: float = 100.0) -> GlbAnimation:
    """Read animation ``index`` of a .glb with one skin (as
    ``capture2face.gltf.export_glb(rig, path, animation=...)`` writes)."""
    r = GlbReader(path)
    g = r.gltf
    anims = g.get("animations", [])
    if index >= len(anims):
        raise CaptureError(f"{path}: has no animation {index}")
    anim = anims[index]
    skins = g.get("skins", [])
    if not skins:
        raise CaptureError(f"{path}: has no skin")
    nodes = g["nodes"]
    ours = g.get("extras", {}).get("capture2face", {}) if isinstance(g.get("extras"), dict) else {}
    joints = skins[0]["joints"]
    eye_joints = joints[len(ours["bone_names"]):] if ours.get("eye_joints") else []
    joints = joints[: len(joints) - len(eye_joints)]
    times = None
    per_node: dict[tuple[int, str], np.ndarray] = {}
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        t = r.accessor(s["input"])[:, 0]
        if times is None or len(t) > len(times):
            times = t
        per_node[(ch["target"].get("node", -1), ch["target"]["path"])] = r.accessor(s["output"])
    F = len(times)
    parent = {c: p for p, n in enumerate(nodes) for c in n.get("children", [])}

    def translation(node: int) -> np.ndarray:
        if (node, "translation") in per_node:
            return per_node[(node, "translation")].astype(np.float64)
        return np.broadcast_to(np.asarray(nodes[node].get("translation", [0.0, 0.0, 0.0]), np.float64), (F, 3))

    joint_set = set(joints)
    pos = np.zeros((F, len(joints), 3))
    for b, node in enumerate(joints):
        n = node
        while n in joint_set:  # compose up to (not including) the skeleton root
            pos[:, b] += translation(n)
            n = parent.get(n, -1)
    mesh_nodes = [i for i, n in enumerate(nodes) if "mesh" in n]
    weights, names = None, []
    if mesh_nodes:
        mesh = g["meshes"][nodes[mesh_nodes[0]]["mesh"]]
        names = list(mesh.get("extras", {}).get("targetNames", []))
        w = per_node.get((mesh_nodes[0], "weights"))
        if w is not None:
            weights = w.reshape(F, -1).astype(np.float32)
    root = skins[0].get("skeleton")
    rot = per_node.get((root, "rotation")) if root is not None else None
    return GlbAnimation(
        times=times.astype(np.float32), joint_names=[nodes[j].get("name", "") for j in joints],
        bone_positions=pos * cm_per_unit, target_names=names, weights=weights,
        root_rotation=None if rot is None else rot.astype(np.float32),
        eye_rotation=np.stack([per_node[(j, "rotation")] for j in eye_joints], 1).astype(np.float32)
        if eye_joints and all((j, "rotation") in per_node for j in eye_joints) else None,
    )


def read_animation_keyframe_count(path: str | os.PathLike, index: int = 0) -> int:
    """Number of keyframes of animation ``index`` (the longest sampler input)."""
    r = GlbReader(path)
    anims = r.gltf.get("animations", [])
    if index >= len(anims):
        raise CaptureError(f"{path}: has no animation {index}")
    accessors = r.gltf["accessors"]
    return max(int(accessors[s["input"]]["count"]) for s in anims[index]["samplers"])

"""``animation.glb`` for a user's own character: their .glb as it is (every mesh,
material, skin and extension kept) plus one glTF animation of the performance, read and
written with pygltflib.

One animation, sampled once per frame (LINEAR), all samplers sharing one time accessor:

* a ``weights`` channel on every mesh node with morph targets: each target takes the
  animation's weight of the rig morph of its name (the import's matching: ARKit names in
  any spelling, the mapping JSON's ``morphs``), other targets 0;
* the head rotation: a ``rotation`` channel on the head joint (the import's choice,
  :func:`capture2face.gltf.rig_import._find_head`), its rest rotation turned by the
  tracked rotation in scene axes; without a head joint, ``rotation`` and
  ``translation`` channels on a new root node over the scene that turn the whole
  character about its face centre.

glTF has no frame rate: ``animations[0].extras`` carries ``{"fps": ..., "frames": F}``.
"""

from __future__ import annotations

import os
import struct
import warnings
from pathlib import Path

import numpy as np
import pygltflib

from capture2face.camera import face_centre_and_height
from capture2face.errors import CaptureError
from capture2face.gltf.animation_export import _frame_times
from capture2face.gltf.container import ROOT_NODE_NAME
from capture2face.gltf.rig_import import (
    _find_head,
    _load_mapping,
    _morph_key,
    _quat_matrix,
    _world_matrices,
)
from capture2face.io.atomic import write_bytes_atomic
from capture2face.maths.rotations import head_rotations, nearest_rotation, rotation_part
from capture2face.rig.arkit_names import canonical_arkit
from capture2face.rig.face_rig import FaceRig


class _Blob:
    """Appends accessors to the file's binary buffer (4-byte aligned views)."""

    def __init__(self, gltf: pygltflib.GLTF2):
        self.gltf = gltf
        self.data = bytearray(gltf.binary_blob() or b"")
        if not gltf.buffers:
            gltf.buffers.append(pygltflib.Buffer(byteLength=0))

    def accessor(self, array: np.ndarray, gltf_type: str, minmax: bool = False) -> int:
        array = np.ascontiguousarray(array, np.float32)
        self.data.extend(b"\0" * (-len(self.data) % 4))
        self.gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(self.data),
                                                          byteLength=array.nbytes))
        self.data.extend(array.tobytes())
        flat = array.reshape(len(array), -1)
        acc = pygltflib.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=pygltflib.FLOAT,
                                 count=len(array), type=gltf_type)
        if minmax:
            acc.min = [float(v) for v in flat.min(0)]
            acc.max = [float(v) for v in flat.max(0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def finish(self) -> None:
        self.data.extend(b"\0" * (-len(self.data) % 4))
        self.gltf.buffers[0].byteLength = len(self.data)
        self.gltf.buffers[0].uri = None
        self.gltf.set_binary_blob(bytes(self.data))


def _load(path: Path) -> pygltflib.GLTF2:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # dataclasses_json's notes on optional fields
            gltf = pygltflib.GLTF2().load(str(path))
    except (ValueError, KeyError, TypeError, AttributeError, struct.error, UnicodeDecodeError) as exc:
        # The import read this file already; a parse failure here is its content.
        raise CaptureError(f"{path}: not a readable glTF file ({exc.__class__.__name__}: {exc})") from None
    if gltf is None:
        raise CaptureError(f"{path}: not a readable glTF file")
    if path.suffix.lower() == ".gltf":
        gltf.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
    return gltf


def _world(gltf: pygltflib.GLTF2) -> tuple[list[np.ndarray], dict[int, int]]:
    nodes = [{k: v for k, v in (("matrix", n.matrix), ("rotation", n.rotation), ("scale", n.scale),
                                ("translation", n.translation), ("children", n.children)) if v} for n in gltf.nodes]
    parent = {c: p for p, n in enumerate(gltf.nodes) for c in (n.children or [])}
    return _world_matrices(nodes), parent


def export_character_animation(source: str | os.PathLike, rig: FaceRig, animation, path: str | os.PathLike,
                               mapping_json: str | os.PathLike | None = None, fps: float | None = None) -> None:
    """Write ``source`` (the user's .glb/.gltf that ``rig`` was imported from) with the
    animation of ``animation`` to ``path`` (a .glb, atomically). See the module docs."""
    source = Path(source)
    F = animation.n_frames
    if F == 0:
        raise CaptureError("the animation has no frames; nothing to export")
    gltf = _load(source)
    mapping, _ = _load_mapping(source, mapping_json)
    renames = {str(k): canonical_arkit(str(v)) for k, v in mapping.get("morphs", {}).items()}
    blob = _Blob(gltf)
    times = _frame_times(animation, fps)
    samplers, channels = [], []
    t_acc = blob.accessor(times, "SCALAR", minmax=True)

    def channel(output: int, node: int, target: str) -> None:
        samplers.append(pygltflib.AnimationSampler(input=t_acc, output=output, interpolation="LINEAR"))
        channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1,
                                                   target=pygltflib.AnimationChannelTarget(node=node, path=target)))

    # Morph weights: per mesh node, its targets in its own order, by the import's key.
    rig_keys = {_morph_key(n, renames)[0]: m for m, n in enumerate(rig.morph_names)}
    src = {n: i for i, n in enumerate(animation.blend_names)}
    weights = np.clip(np.nan_to_num(np.asarray(animation.blend_weights, np.float32)), 0.0, 1.0)
    for ni, node in enumerate(gltf.nodes):
        if node.mesh is None:
            continue
        mesh = gltf.meshes[node.mesh]
        n_targets = max((len(p.targets or []) for p in mesh.primitives), default=0)
        if not n_targets:
            continue
        names = (mesh.extras or {}).get("targetNames") or []
        w = np.zeros((F, n_targets), np.float32)
        for t, name in enumerate(names[:n_targets]):
            m = rig_keys.get(_morph_key(str(name), renames)[0])
            if m is not None and rig.morph_names[m] in src:
                w[:, t] = weights[:, src[rig.morph_names[m]]]
        channel(blob.accessor(w.reshape(-1), "SCALAR"), ni, "weights")

    # Head rotation: on the head joint (scene-axis rotation R: local' = P^-1 R P local),
    # else on a root over the scene, about the face centre.
    rot = _rotations(animation.head_pose, F)
    world, parent = _world(gltf)
    joints = sorted({j for s in gltf.skins for j in s.joints})
    head_k = _find_head([gltf.nodes[j].name or "" for j in joints], mapping) if joints else None
    if head_k is not None:
        head = joints[head_k]
        node = gltf.nodes[head]
        p = nearest_rotation(world[parent[head]][:3, :3]) if head in parent else np.eye(3)
        local = _quat_matrix(node.rotation) if node.rotation else np.eye(3)
        if node.matrix:
            raise CaptureError(f"{source}: the head joint '{node.name}' has a matrix transform; "
                               "animated nodes need translation/rotation/scale")
        turned = np.einsum("ij,fjk,kl,lm->fim", p.T, rot, p, local)
        channel(blob.accessor(_quats(turned), "VEC4"), head, "rotation")
    else:
        scene = gltf.scenes[gltf.scene or 0]
        gltf.nodes.append(pygltflib.Node(name=ROOT_NODE_NAME, children=list(scene.nodes)))
        root = len(gltf.nodes) - 1
        scene.nodes = [root]
        centre = face_centre_and_height(rig)[0] / float(mapping.get("scale", 100.0))  # rig cm -> file units
        shift = centre - np.einsum("fij,j->fi", rot, centre)
        channel(blob.accessor(_quats(rot), "VEC4"), root, "rotation")
        channel(blob.accessor(shift.astype(np.float32), "VEC3"), root, "translation")
    gltf.animations.append(pygltflib.Animation(
        name="performance", samplers=samplers, channels=channels,
        extras={"fps": float(fps or animation.fps), "frames": int(F),
                "note": "glTF keeps seconds, not frames: set the scene's frame rate to fps"}))
    blob.finish()
    write_bytes_atomic(path, b"".join(gltf.save_to_bytes()))


def _rotations(head_pose, F: int) -> np.ndarray:
    if head_pose is None or len(head_pose) != F:
        return np.tile(np.eye(3), (F, 1, 1))
    return rotation_part(head_pose)


def _quats(rot: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations -> (F, 4) float32 sign-continuous quaternions (x, y, z, w)."""
    return head_rotations(rot).astype(np.float32)

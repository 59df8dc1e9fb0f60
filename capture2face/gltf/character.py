"""``animation.glb`` for a user's own character: their .glb as it is (every mesh,
material, skin and extension kept) plus one glTF animation of the performance. The JSON
is kept as the file has it (no parser's defaults or rewrites) and the result is
self-contained: a .gltf's buffers and images are embedded.

One animation, sampled once per frame (LINEAR), all samplers sharing one time accessor:

* a ``weights`` channel on every mesh node with morph targets: each target takes the
  animation's weight of the rig morph of its name (the import's matching: ARKit names in
  any spelling, the mapping JSON's ``morphs``), other targets 0; a .vrm's rig morphs are
  its expressions, whose binds give its targets' weights (:func:`.vrm.target_weights`);
* the head rotation: a ``rotation`` channel on the head joint (the import's choice,
  :func:`capture2face.gltf.skins.find_head`), its rest rotation turned by the
  tracked rotation in scene axes; without a head joint, ``rotation`` and
  ``translation`` channels on a new root node over the scene that turn the whole
  character about its face centre.

glTF has no frame rate: ``animations[0].extras`` carries ``{"fps": ..., "frames": F}``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from capture2face.camera import face_centre_and_height
from capture2face.errors import CaptureError
from capture2face.gltf.animation_export import frame_times
from capture2face.gltf.container import ROOT_NODE_NAME, embed_resources, read_gltf_document, write_glb
from capture2face.gltf.mapping import load_mapping
from capture2face.gltf.morphs import morph_key
from capture2face.gltf.scene import parents, world_matrices
from capture2face.gltf.skins import find_head
from capture2face.gltf.vrm import scene_turn, target_weights
from capture2face.io.atomic import write_bytes_atomic
from capture2face.maths.rotations import head_rotations, nearest_rotation, quaternion_matrix, rotation_part
from capture2face.rig.face_rig import FaceRig


class _Blob:
    """Appends float accessors to the file's one binary buffer (4-byte aligned views)."""

    def __init__(self, gltf: dict, binary: bytearray):
        self.gltf = gltf
        self.data = binary

    def accessor(self, array: np.ndarray, gltf_type: str, minmax: bool = False) -> int:
        array = np.ascontiguousarray(array, np.float32)
        self.data.extend(b"\0" * (-len(self.data) % 4))
        views = self.gltf.setdefault("bufferViews", [])
        views.append({"buffer": 0, "byteOffset": len(self.data), "byteLength": array.nbytes})
        self.data.extend(array.tobytes())
        flat = array.reshape(len(array), -1)
        acc = {"bufferView": len(views) - 1, "componentType": 5126, "count": len(array), "type": gltf_type}
        if minmax:
            acc["min"] = [float(v) for v in flat.min(0)]
            acc["max"] = [float(v) for v in flat.max(0)]
        accessors = self.gltf.setdefault("accessors", [])
        accessors.append(acc)
        return len(accessors) - 1


def _load(path: Path) -> tuple[dict, bytearray]:
    """The file's document as it is and one self-contained BIN chunk (a .gltf's buffers
    and images, and data URIs, embedded: animation.glb is moved on its own)."""
    gltf, binary = read_gltf_document(path)
    binary = embed_resources(gltf, binary, str(path.parent), str(path))
    for acc in gltf.get("accessors", []):
        if "bufferView" not in acc:  # all-zero (sparse) accessors: byteOffset needs a view
            acc.pop("byteOffset", None)
    return gltf, binary


def export_character_animation(source: str | os.PathLike, rig: FaceRig, animation, path: str | os.PathLike,
                               mapping_json: str | os.PathLike | None = None, fps: float | None = None) -> None:
    """Write ``source`` (the user's .glb/.gltf that ``rig`` was imported from) with the
    animation of ``animation`` to ``path`` (a .glb, atomically). See the module docs."""
    source = Path(source)
    F = animation.n_frames
    if F == 0:
        raise CaptureError("the animation has no frames; nothing to export")
    gltf, binary = _load(source)
    mapping = load_mapping(source, mapping_json)
    renames = mapping.arkit_renames()
    blob = _Blob(gltf, binary)
    times = frame_times(animation, fps)
    samplers, channels = [], []
    t_acc = blob.accessor(times, "SCALAR", minmax=True)

    def channel(output: int, node: int, target: str) -> None:
        samplers.append({"input": t_acc, "output": output, "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": target}})

    # Morph weights: per mesh node, its targets in its own order, by the import's key.
    rig_keys = {morph_key(n, renames)[0]: m for m, n in enumerate(rig.morph_names)}
    src = {n: i for i, n in enumerate(animation.blend_names)}
    weights = np.clip(np.nan_to_num(np.asarray(animation.blend_weights, np.float32)), 0.0, 1.0)
    for ni, node in enumerate(gltf.get("nodes", [])):
        if node.get("mesh") is None:
            continue
        mesh = gltf["meshes"][node["mesh"]]
        n_targets = max((len(p.get("targets") or []) for p in mesh.get("primitives", [])), default=0)
        if not n_targets:
            continue
        names = (mesh.get("extras") or {}).get("targetNames") or []
        w = np.zeros((F, n_targets), np.float32)
        if rig.morph_rules is not None:  # a .vrm's morphs are its expressions: their binds, expanded
            names = []
            w = target_weights(gltf, ni, n_targets, {n: weights[:, src[n]] for n in rig.morph_names if n in src})
        for t, name in enumerate(names[:n_targets]):
            m = rig_keys.get(morph_key(str(name), renames)[0])
            if m is not None and rig.morph_names[m] in src:
                w[:, t] = weights[:, src[rig.morph_names[m]]]
        channel(blob.accessor(w.reshape(-1), "SCALAR"), ni, "weights")

    # Head rotation: on the head joint (scene-axis rotation R: local' = P^-1 R P local),
    # else on a root over the scene, about the face centre.
    turn = scene_turn(gltf)  # the rig's axes -> the file's (a VRM 0.x faces -z)
    rot = np.einsum("ji,fjk,kl->fil", turn, _rotations(animation.head_pose, F), turn)
    nodes = gltf.get("nodes", [])
    world, parent = world_matrices(nodes), parents(nodes)
    joints = sorted({j for s in gltf.get("skins", []) for j in s.get("joints", [])})
    head_k = find_head([nodes[j].get("name") or "" for j in joints], mapping.head_bone) if joints else None
    if head_k is not None:
        head = joints[head_k]
        node = nodes[head]
        p = nearest_rotation(world[parent[head]][:3, :3]) if head in parent else np.eye(3)
        local = quaternion_matrix(node["rotation"]) if node.get("rotation") else np.eye(3)
        if node.get("matrix"):
            raise CaptureError(f"{source}: the head joint '{node.get('name')}' has a matrix transform; "
                               "animated nodes need translation/rotation/scale")
        turned = np.einsum("ij,fjk,kl,lm->fim", p.T, rot, p, local)
        channel(blob.accessor(_quats(turned), "VEC4"), head, "rotation")
    else:
        scene = gltf["scenes"][gltf.get("scene", 0)]
        nodes.append({"name": ROOT_NODE_NAME, "children": list(scene.get("nodes", []))})
        root = len(nodes) - 1
        scene["nodes"] = [root]
        scale = float(mapping.scale if mapping.scale is not None else 100.0)
        centre = turn.T @ face_centre_and_height(rig)[0] / scale  # rig cm -> file units
        shift = centre - np.einsum("fij,j->fi", rot, centre)
        channel(blob.accessor(_quats(rot), "VEC4"), root, "rotation")
        channel(blob.accessor(shift.astype(np.float32), "VEC3"), root, "translation")
    gltf.setdefault("animations", []).append({
        "name": "performance", "samplers": samplers, "channels": channels,
        "extras": {"fps": float(fps or animation.fps), "frames": int(F),
                   "note": "glTF keeps seconds, not frames: set the scene's frame rate to fps"}})
    write_bytes_atomic(path, write_glb(gltf, blob.data))


def _rotations(head_pose, F: int) -> np.ndarray:
    if head_pose is None or len(head_pose) != F:
        return np.tile(np.eye(3), (F, 1, 1))
    return rotation_part(head_pose)


def _quats(rot: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations -> (F, 4) float32 sign-continuous quaternions (x, y, z, w)."""
    return head_rotations(rot).astype(np.float32)

"""A FaceRig as a third-party ARKit character would ship: several meshes (head, eyes,
mouth interior, optionally a body), each with only the ARKit morphs that move it, under
another naming convention, no face bones and no capture2face extras.

:func:`export_arkit_character` is how the tests and ``capture2face avatar --export-arkit``
make characters like the ones users bring (Ready Player Me, Face Cap, Character Creator)
without a third-party asset: the default avatar's ARKit morphs, renamed
(``eyeBlinkLeft`` -> ``eyeBlink_L``, ``eyeBlink.L``, ``blendShape1.eyeBlinkLeft``, ...),
optionally with a skeleton (hips -> neck -> head, the body on the hips, the head on the
head joint) and stored with ``KHR_mesh_quantization`` (int16 positions and morph deltas,
dequantized by the node's scale and translation).
"""

from __future__ import annotations

import os

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import (
    ARRAY_BUFFER,
    ELEMENT_ARRAY_BUFFER,
    METRES_PER_CM,
    SAMPLER_LINEAR_CLAMP,
    GlbBuilder,
)
from capture2face.io.atomic import write_bytes_atomic
from capture2face.rig.arkit_names import canonical_arkit
from capture2face.rig.face_rig import FaceRig

NAMINGS = ("arkit", "_L", ".L", "Left_", "blendShape1.")
# FaceRig material code -> mesh name (others: "Part<code>")
PART_NAMES = {0: "Head", 1: "Eyes", 2: "Mouth", 3: "Teeth", 4: "Scalp"}


def part_order(rig: FaceRig) -> np.ndarray:
    """(V,) the rig's vertex indices in the order the export writes them: one mesh per
    material code, in code order."""
    return np.concatenate([np.flatnonzero(rig.material == c) for c in np.unique(rig.material)])


_MOVES = 1e-6  # cm: a morph whose deltas on a mesh stay below this does not go on it


def arkit_style_name(name: str, naming: str) -> str:
    """``eyeBlinkLeft`` in a naming convention: ``arkit`` (as is), ``_L`` (Face Cap:
    ``eyeBlink_L``), ``.L`` (Blender: ``eyeBlink.L``), ``Left_`` (capitalised,
    ``EyeBlink_Left``), ``blendShape1.`` (Maya: ``blendShape1.eyeBlinkLeft``)."""
    if naming not in NAMINGS:
        raise CaptureError(f"unknown naming '{naming}'; choose one of {', '.join(NAMINGS)}")
    if naming == "arkit":
        return name
    if naming == "blendShape1.":
        return "blendShape1." + name
    base, side = name, ""
    for s in ("Left", "Right"):
        if name.endswith(s) and canonical_arkit(name[: -len(s)]) is None:
            base, side = name[: -len(s)], s
    if naming == "Left_":
        return base[:1].upper() + base[1:] + (f"_{side}" if side else "")
    sep = "_" if naming == "_L" else "."
    return base + (f"{sep}{side[0]}" if side else "")


def _quantize(values: np.ndarray, step: float, offset: np.ndarray) -> np.ndarray:
    q = np.rint((values - offset) / step)
    if np.abs(q).max(initial=0) > 32767:
        raise CaptureError("quantization step too small for the mesh's extent")
    return q.astype(np.int16)


def _padded_vec3(bld: GlbBuilder, q: np.ndarray, minmax: bool) -> int:
    """A VEC3 int16 accessor on a view with byteStride 8 (vertex attributes align to 4 bytes)."""
    data = np.zeros((len(q), 4), np.int16)
    data[:, :3] = q
    view = bld.buffer_view(data.tobytes(), ARRAY_BUFFER)
    bld.gltf["bufferViews"][view]["byteStride"] = 8
    acc = {"bufferView": view, "componentType": 5122, "count": int(len(q)), "type": "VEC3"}
    if minmax and len(q):
        acc["min"] = q.min(0).astype(int).tolist()
        acc["max"] = q.max(0).astype(int).tolist()
    return bld.add("accessors", acc)


def export_arkit_character(rig: FaceRig, path: str | os.PathLike, naming: str = "_L", quantize: bool = False,
                           skeleton: bool = False, body: bool = False) -> None:
    """Write ``rig`` as a morph-only, multi-mesh ARKit character .glb (atomically).

    Args:
        naming: morph naming convention (:func:`arkit_style_name`).
        quantize: ``KHR_mesh_quantization``: int16 positions and morph deltas (0.02 mm steps).
        skeleton: a skin with joints Hips -> Neck -> Head; every face mesh on Head.
        body: also a body mesh (a box under the head, its own textured material, on Hips).
    """
    bld = GlbBuilder(generator="capture2face arkit export")
    if quantize:
        bld.gltf["extensionsUsed"] = ["KHR_mesh_quantization"]
        bld.gltf["extensionsRequired"] = ["KHR_mesh_quantization"]
    sampler = bld.add("samplers", dict(SAMPLER_LINEAR_CLAMP))
    skin_tex = bld.add("textures", {"sampler": sampler, "source": bld.image_png(rig.albedo, "face_albedo")})
    nrm_tex = bld.add("textures", {"sampler": sampler, "source": bld.image_png(rig.normal_map, "face_normal")})
    face_mat = bld.add("materials", {"name": "Face", "pbrMetallicRoughness": {"baseColorTexture": {"index": skin_tex},
                                                                             "metallicFactor": 0.0},
                                     "normalTexture": {"index": nrm_tex}})
    arkit = [(m, n) for m, n in enumerate(rig.morph_names) if canonical_arkit(n) is not None]
    step = 2e-5  # metres: 0.02 mm (a 65 cm extent in int16)
    mesh_nodes = []
    offset = (rig.vertices.astype(np.float64).min(0) + rig.vertices.astype(np.float64).max(0)) / 2 * METRES_PER_CM
    for code in np.unique(rig.material):
        part = PART_NAMES.get(int(code), f"Part{int(code)}")
        sel = np.flatnonzero(rig.material == code)
        remap = np.full(rig.n_vertices, -1, np.int64)
        remap[sel] = np.arange(len(sel))
        tris = remap[rig.triangles[np.all(rig.material[rig.triangles] == code, axis=1)]]
        pos = rig.vertices[sel].astype(np.float64) * METRES_PER_CM
        if quantize:
            position = _padded_vec3(bld, _quantize(pos, step, offset), minmax=True)
        else:
            position = bld.accessor(pos.astype(np.float32), ARRAY_BUFFER, minmax=True)
        attrs = {"POSITION": position,
                 "NORMAL": bld.accessor(rig.normals[sel].astype(np.float32), ARRAY_BUFFER),
                 "TEXCOORD_0": bld.accessor(rig.uvs[sel].astype(np.float32), ARRAY_BUFFER)}
        if skeleton:
            attrs["JOINTS_0"] = bld.accessor(np.tile(np.array([2, 0, 0, 0], np.uint8), (len(sel), 1)), ARRAY_BUFFER)
            attrs["WEIGHTS_0"] = bld.accessor(np.tile(np.array([1, 0, 0, 0], np.float32), (len(sel), 1)), ARRAY_BUFFER)
        targets, names = [], []
        for m, name in arkit:
            delta = rig.morph_positions[m, sel].astype(np.float64) * METRES_PER_CM
            if np.abs(delta).max(initial=0) * 100 < _MOVES:
                continue
            acc = _padded_vec3(bld, _quantize(delta, step, 0.0), minmax=True) if quantize \
                else bld.accessor(delta.astype(np.float32), ARRAY_BUFFER, minmax=True)
            targets.append({"POSITION": acc})
            names.append(arkit_style_name(name, naming))
        prim = {"attributes": attrs, "material": face_mat, "mode": 4,
                "indices": bld.accessor(tris.astype(np.uint32).ravel(), ELEMENT_ARRAY_BUFFER)}
        mesh = {"name": part, "primitives": [prim]}
        if targets:
            prim["targets"] = targets
            mesh["weights"] = [0.0] * len(targets)
            mesh["extras"] = {"targetNames": names}
        node = {"name": part, "mesh": bld.add("meshes", mesh)}
        if quantize:  # dequantization: position = translation + scale * q
            node["scale"] = [step] * 3
            node["translation"] = offset.tolist()
        mesh_nodes.append(bld.add("nodes", node))
    scene_nodes = list(mesh_nodes)
    if body:
        scene_nodes.append(_add_body(bld, rig, sampler, skeleton, step if quantize else None, offset))
    if skeleton:
        _add_skeleton(bld, rig, list(scene_nodes), quantize, step, offset, scene_nodes)
    bld.gltf["scenes"] = [{"name": rig.name, "nodes": scene_nodes}]
    bld.gltf["scene"] = 0
    write_bytes_atomic(path, bld.to_bytes())


def _add_body(bld: GlbBuilder, rig: FaceRig, sampler: int, skinned: bool, step: float | None,
              offset: np.ndarray) -> int:
    """A box (torso) under the head with a texture of its own: a second base-colour
    texture, which the import packs into an atlas beside the face's."""
    lo, hi = rig.vertices.min(0).astype(np.float64), rig.vertices.max(0).astype(np.float64)
    cx, cz = (lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2 - 2.0
    w, top, bottom, d = 1.6 * (hi[0] - lo[0]), lo[1] - 4.0, lo[1] - 40.0, 0.8 * (hi[2] - lo[2])
    corners = np.array([[x, y, z] for y in (bottom, top) for z in (cz - d / 2, cz + d / 2)
                        for x in (cx - w / 2, cx + w / 2)]) * METRES_PER_CM
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    pos, uv, tris = [], [], []
    for f in faces:  # 4 vertices per face: flat normals, a UV square each
        base = len(pos)
        pos += [corners[i] for i in f]
        uv += [[0, 0], [1, 0], [1, 1], [0, 1]]
        tris += [[base, base + 1, base + 2], [base, base + 2, base + 3]]  # faces listed CCW from outside
    pos = np.asarray(pos, np.float32)
    cloth = np.zeros((8, 8, 3), np.uint8)
    cloth[:] = (40, 70, 150)
    cloth[::2, ::2] = (60, 90, 170)
    tex = bld.add("textures", {"sampler": sampler, "source": bld.image_png(cloth, "body_albedo")})
    mat = bld.add("materials", {"name": "Outfit", "pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}})
    position = _padded_vec3(bld, _quantize(pos, step, offset), minmax=True) if step \
        else bld.accessor(pos, ARRAY_BUFFER, minmax=True)
    attrs = {"POSITION": position,
             "TEXCOORD_0": bld.accessor(np.asarray(uv, np.float32), ARRAY_BUFFER)}
    if skinned:
        attrs["JOINTS_0"] = bld.accessor(np.zeros((len(pos), 4), np.uint8), ARRAY_BUFFER)
        attrs["WEIGHTS_0"] = bld.accessor(np.tile(np.array([1, 0, 0, 0], np.float32), (len(pos), 1)), ARRAY_BUFFER)
    mesh = bld.add("meshes", {"name": "Body", "primitives": [{
        "attributes": attrs, "material": mat, "mode": 4,
        "indices": bld.accessor(np.asarray(tris, np.uint16).ravel(), ELEMENT_ARRAY_BUFFER)}]})
    node = {"name": "Body", "mesh": mesh}
    if step:
        node["scale"] = [step] * 3
        node["translation"] = offset.tolist()
    return bld.add("nodes", node)


def _add_skeleton(bld: GlbBuilder, rig: FaceRig, mesh_nodes: list[int], quantize: bool, step: float,
                  offset: np.ndarray, scene_nodes: list[int]) -> None:
    """Hips -> Neck -> Head (metres), one skin for every mesh; the head joint sits at the
    back of the jaw line (where a head turns), the neck below it, the hips at the body."""
    lo, hi = rig.vertices.min(0).astype(np.float64), rig.vertices.max(0).astype(np.float64)
    head = np.array([(lo[0] + hi[0]) / 2, lo[1] + 0.25 * (hi[1] - lo[1]), (lo[2] + hi[2]) / 2 - 3.0]) * METRES_PER_CM
    neck = head + np.array([0.0, -0.08, 0.0])
    hips = head + np.array([0.0, -0.5, 0.0])
    first = len(bld.gltf["nodes"])
    bld.add("nodes", {"name": "Hips", "translation": hips.tolist(), "children": [first + 1]})
    bld.add("nodes", {"name": "Neck", "translation": (neck - hips).tolist(), "children": [first + 2]})
    bld.add("nodes", {"name": "Head", "translation": (head - neck).tolist()})
    rest = np.stack([hips, neck, head])
    ibm = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    ibm[:, 3, :3] = -rest
    if quantize:  # the quantized meshes' bind space is their quantized space
        dq = np.eye(4)
        dq[:3, :3] *= step
        dq[:3, 3] = offset
        ibm = np.stack([(_translation(-r) @ dq).T for r in rest]).astype(np.float32)
    skin = bld.add("skins", {"joints": [first, first + 1, first + 2], "skeleton": first,
                             "inverseBindMatrices": bld.accessor(ibm.reshape(3, 16), gltf_type="MAT4")})
    for n in mesh_nodes:
        node = bld.gltf["nodes"][n]
        node["skin"] = skin
        node.pop("scale", None)  # a skinned mesh ignores its node's transform: the IBMs dequantize
        node.pop("translation", None)
    scene_nodes.append(first)


def _translation(t: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m

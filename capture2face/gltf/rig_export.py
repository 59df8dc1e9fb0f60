"""glTF 2.0 binary (.glb) export of a :class:`FaceRig` (optionally with an animation) and
import of a user's character (:func:`import_glb`, see :mod:`capture2face.gltf.rig_import`).

What an exported .glb holds (it passes the Khronos glTF validator without errors):

* **Units and axes.** glTF is +y up, +z forward, metres; head coordinates are +y up, +z
  out of the face, centimetres. Axes therefore match and every length (positions, morph
  deltas, joint translations, inverse bind matrices, animation translations) is written in
  metres = cm * 0.01 (``METRES_PER_CM``); :func:`import_glb` multiplies by 100. A float32
  round trip through metres changes a coordinate by at most one float32 ulp of its cm
  value (< 2e-6 cm for |x| < 32 cm, which covers a head with its neck), so vertices come
  back within 2e-6 cm; the rig's exact bone and pose positions (cm) are also kept in ``extras``.
* **One mesh, one primitive** (skin, eyes and mouth interior together, so vertex order and
  indices survive a round trip) with POSITION, NORMAL, TANGENT, TEXCOORD_0, JOINTS_0
  (unsigned byte, or short for > 255 bones), WEIGHTS_0 (float, rows sum to 1), and
  application-specific attributes ``_POSITION_ID``, ``_MATERIAL`` (float scalars) and
  ``_REGIONS_0``, ``_REGIONS_1``, ... (VEC4, the rig's region weights, zero padded).
  Morph targets carry POSITION and NORMAL deltas; their names are in
  ``mesh.extras.targetNames`` (the convention Blender and three.js read).
* **Skin.** One joint node per bone named after it, nested as ``bone_parents`` says, each
  translated relative to its parent (bones translate only); bone 0 ``head`` hangs under a
  root node ``capture2face_root`` (the skeleton root, which carries the head rotation of
  an animation). Inverse bind matrices are translations by minus the rest positions.
  A rig with turning eyes (``FaceRig.eye_centres``) gets two more joints after the
  bones, ``eye_R`` and ``eye_L`` (children of ``head``, at the eye centres): its eyeball
  vertices are skinned to them alone, so an animation turns the eyes by rotating them.
* **Textures** (PNG): the albedo as baseColorTexture (RGBA with ``FaceRig.alpha``), the
  base normal map as normalTexture; the wrinkle maps and the two RGBA zone masks as
  further images. A rig with alpha modes gets one primitive per mode (and MASK cutoff),
  on the same vertices, each with its material's ``alphaMode`` / ``alphaCutoff``.
* **``extras.capture2face``** at the top level: everything else a FaceRig has (bone
  landmarks, groups and exact rest positions, reference poses, wrinkle-map and zone-mask
  image indices, zone table, region names, tracker landmark vertices), as JSON.
* **Animation** (when given): see :mod:`capture2face.gltf.animation_export`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.animation_export import add_animation
from capture2face.gltf.container import (
    ARRAY_BUFFER,
    CM_PER_METRE,
    ELEMENT_ARRAY_BUFFER,
    EXTRAS_FORMAT,
    EXTRAS_KEY,
    EYE_JOINT_NAMES,
    METRES_PER_CM,
    ROOT_NODE_NAME,
    SAMPLER_LINEAR_CLAMP,
    GlbBuilder,
)
from capture2face.gltf.rig_import import import_glb as _import
from capture2face.io.atomic import write_bytes_atomic
from capture2face.rig.face_rig import FaceRig


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v.astype(np.float64), axis=-1, keepdims=True)
    return (v / np.maximum(n, 1e-12)).astype(np.float32)


def _tolist(a: np.ndarray) -> list:
    """float32 arrays become Python floats that print (and parse back) exactly."""
    a = np.asarray(a)
    if a.dtype.kind == "f":
        return a.astype(np.float64).tolist()
    return a.astype(np.int64).tolist()


def _skin_attributes(rig: FaceRig) -> tuple[np.ndarray, np.ndarray]:
    """JOINTS_0 / WEIGHTS_0 as the validator wants them: zero-weight slots point at joint 0
    (a non-zero joint at weight 0 is a warning), and the float32 rounding residue of each
    row sum sits on its largest weight (non-normalized rows are an error)."""
    joints = rig.skin_joints.astype(np.int64).copy()
    weights = rig.skin_weights.astype(np.float32).copy()
    k = joints.shape[1]
    if k > 4:
        raise CaptureError(f"rig '{rig.name}' has {k} skin influences per vertex; glTF export supports 4")
    if k < 4:
        joints = np.concatenate([joints, np.zeros((len(joints), 4 - k), np.int64)], 1)
        weights = np.concatenate([weights, np.zeros((len(weights), 4 - k), np.float32)], 1)
    unused = weights <= 0.0
    weights[unused] = 0.0
    joints[unused] = 0
    top = np.argmax(weights, axis=1)
    rows = np.arange(len(weights))
    weights[rows, top] += np.float32(1.0) - weights.sum(1, dtype=np.float32)
    return joints, weights


def _joint_order_check(rig: FaceRig) -> None:
    parents = rig.bone_parents.astype(np.int64)
    if rig.bone_names[0] != "head" or parents[0] != -1:
        raise CaptureError(f"rig '{rig.name}': bone 0 must be the root 'head' bone")
    for i in range(1, rig.n_bones):  # every chain must reach a root without a cycle
        j, steps = i, 0
        while parents[j] >= 0:
            j = parents[j]
            steps += 1
            if steps > rig.n_bones:
                raise CaptureError(f"rig '{rig.name}': bone_parents has a cycle through bone {i}")


@dataclass
class _Geometry:
    """The accessors of the mesh's primitives (one per alpha group, sharing attributes)."""

    attributes: dict
    indices: list  # per alpha group
    targets: list
    n_region_chunks: int  # _REGIONS_0 .. _REGIONS_{n-1}


@dataclass
class _Textures:
    """The skin materials (one per alpha group) and the images the extras point at."""

    materials: list
    wrinkle_images: list
    zone_images: list


def _vertex_attributes(b: GlbBuilder, rig: FaceRig) -> tuple[dict, int]:
    """The primitive's vertex attributes; returns them and the number of ``_REGIONS_``
    chunks."""
    V = rig.n_vertices
    tangents = rig.tangents.astype(np.float32).copy()
    tangents[:, :3] = _unit(tangents[:, :3])
    tangents[:, 3] = np.where(tangents[:, 3] < 0, -1.0, 1.0)
    joints, weights = _skin_attributes(rig)
    if rig.has_eyes:  # eyeballs ride their eye joints (after the bones) alone
        eye = rig.eye_vertex_side >= 0
        joints[eye] = 0
        joints[eye, 0] = rig.n_bones + rig.eye_vertex_side[eye]
        weights[eye] = [1.0, 0.0, 0.0, 0.0]
    joint_dtype = np.uint8 if rig.n_bones + 2 <= 256 else np.uint16
    attributes = {
        "POSITION": b.accessor(rig.vertices.astype(np.float32) * np.float32(METRES_PER_CM), ARRAY_BUFFER, minmax=True),
        "NORMAL": b.accessor(_unit(rig.normals), ARRAY_BUFFER),
        "TANGENT": b.accessor(tangents, ARRAY_BUFFER),
        "TEXCOORD_0": b.accessor(rig.uvs.astype(np.float32), ARRAY_BUFFER),
        "JOINTS_0": b.accessor(joints.astype(joint_dtype), ARRAY_BUFFER),
        "WEIGHTS_0": b.accessor(weights, ARRAY_BUFFER),
        "_POSITION_ID": b.accessor(rig.position_ids.astype(np.float32), ARRAY_BUFFER),
        "_MATERIAL": b.accessor(rig.material.astype(np.float32), ARRAY_BUFFER),
    }
    if int(rig.position_ids.max(initial=0)) >= 1 << 24:
        raise CaptureError(f"rig '{rig.name}': too many vertex positions for the _POSITION_ID attribute")
    regions = rig.region_weights.astype(np.float32)
    n_chunks = -(-len(regions) // 4)
    padded = np.zeros((n_chunks * 4, V), np.float32)
    padded[: len(regions)] = regions
    for c in range(n_chunks):
        attributes[f"_REGIONS_{c}"] = b.accessor(np.ascontiguousarray(padded[4 * c: 4 * c + 4].T), ARRAY_BUFFER)
    return attributes, n_chunks


def _alpha_groups(rig: FaceRig) -> list[tuple[int, float, np.ndarray]]:
    """(alpha mode, cutoff, triangle ids) of each material the rig needs: one opaque
    group without ``alpha_mode``, else one per (mode, MASK cutoff) of the triangles' last
    vertices (a triangle's mode, as the renderer draws it), opaque first."""
    if rig.alpha_mode is None:
        return [(0, 0.5, np.arange(len(rig.triangles)))]
    last = rig.triangles[:, 2]
    mode = np.asarray(rig.alpha_mode)[last].astype(np.int64)
    cutoff = np.where(mode == 1, np.asarray(rig.alpha_cutoff, np.float32)[last], np.float32(0.5))
    keys = sorted(set(zip(mode.tolist(), cutoff.tolist())))
    return [(m, c, np.flatnonzero((mode == m) & (cutoff == np.float32(c)))) for m, c in keys]


def _add_geometry(b: GlbBuilder, rig: FaceRig, groups: list) -> _Geometry:
    """Vertex attributes, triangle indices (per alpha group) and morph targets."""
    attributes, n_chunks = _vertex_attributes(b, rig)
    indices_dtype = np.uint16 if rig.n_vertices <= 65535 else np.uint32
    indices = [b.accessor(rig.triangles[tris].astype(indices_dtype).ravel(), ELEMENT_ARRAY_BUFFER)
               for _, _, tris in groups]

    targets = []
    for m in range(rig.n_morphs):
        targets.append({
            "POSITION": b.accessor(rig.morph_positions[m].astype(np.float32) * np.float32(METRES_PER_CM),
                                   ARRAY_BUFFER, minmax=True),
            "NORMAL": b.accessor(rig.morph_normals[m].astype(np.float32), ARRAY_BUFFER),
        })
    return _Geometry(attributes, indices, targets, n_chunks)


def _add_textures(b: GlbBuilder, rig: FaceRig, groups: list) -> _Textures:
    """The albedo (with its alpha where the rig has one) and normal map in the skin
    material, one per alpha group; wrinkle maps and zone masks as further images."""
    sampler = b.add("samplers", dict(SAMPLER_LINEAR_CLAMP))
    albedo = rig.albedo if rig.alpha is None else np.concatenate([rig.albedo, rig.alpha[:, :, None]], axis=2)
    albedo_img = b.image_png(albedo, "albedo")
    normal_img = b.image_png(rig.normal_map, "normal_map")
    albedo_tex = b.add("textures", {"sampler": sampler, "source": albedo_img, "name": "albedo"})
    normal_tex = b.add("textures", {"sampler": sampler, "source": normal_img, "name": "normal_map"})
    materials = []
    for mode, cutoff, _ in groups:
        material = {
            "name": f"{rig.name}_skin" + ("", "_mask", "_blend")[mode],
            "pbrMetallicRoughness": {
                "baseColorTexture": {"index": albedo_tex},
                "metallicFactor": 0.0,
                "roughnessFactor": 0.6,
            },
            "normalTexture": {"index": normal_tex},
            "doubleSided": bool(rig.double_sided),
        }
        if mode:
            material["alphaMode"] = ("OPAQUE", "MASK", "BLEND")[mode]
        if mode == 1:
            material["alphaCutoff"] = float(cutoff)
        materials.append(b.add("materials", material))
    wrinkle_images = [b.image_png(rig.wrinkle_maps[k], f"wrinkle_{name}")
                      for k, name in enumerate(rig.wrinkle_map_names)]
    zone_images = [b.image_png(np.ascontiguousarray(rig.zone_masks[:, :, 4 * i: 4 * i + 4]), f"zone_mask_{i}")
                   for i in range(rig.zone_masks.shape[2] // 4)]
    return _Textures(materials, wrinkle_images, zone_images)


def _add_mesh(b: GlbBuilder, rig: FaceRig, geometry: _Geometry, materials: list) -> int:
    """The mesh: one primitive per alpha group, all on the same vertices; returns its index."""
    primitives = [{"attributes": geometry.attributes, "indices": indices, "material": material, "mode": 4}
                  for indices, material in zip(geometry.indices, materials)]
    mesh_obj = {"name": rig.name or "face", "primitives": primitives}
    if geometry.targets:
        for primitive in primitives:
            primitive["targets"] = geometry.targets
        mesh_obj["weights"] = [0.0] * rig.n_morphs
        mesh_obj["extras"] = {"targetNames": list(rig.morph_names)}
    return b.add("meshes", mesh_obj)


def _add_skeleton(b: GlbBuilder, rig: FaceRig, mesh: int) -> dict:
    """The mesh node, the root node, one joint node per bone (and the eye joints), the
    skin and the scene. Returns the node indices an animation targets."""
    rest = rig.bone_rest.astype(np.float64)
    parents = rig.bone_parents.astype(np.int64)
    mesh_node = b.add("nodes", {"name": rig.name or "face", "mesh": mesh})
    root_node = b.add("nodes", {"name": ROOT_NODE_NAME})
    first_joint = len(b.gltf["nodes"])
    joint_nodes = [first_joint + i for i in range(rig.n_bones)]
    for i, name in enumerate(rig.bone_names):
        rel = rest[i] - (rest[parents[i]] if parents[i] >= 0 else 0.0)
        node = {"name": name, "translation": (rel * METRES_PER_CM).tolist()}
        children = [joint_nodes[c] for c in np.flatnonzero(parents == i)]
        if children:
            node["children"] = children
        b.add("nodes", node)
    b.gltf["nodes"][root_node]["children"] = [joint_nodes[i] for i in np.flatnonzero(parents < 0)]
    eye_nodes, joint_rest = [], rest
    if rig.has_eyes:
        centres = rig.eye_centres.astype(np.float64)
        for side, name in enumerate(EYE_JOINT_NAMES):
            eye_nodes.append(b.add("nodes", {"name": name,
                                             "translation": ((centres[side] - rest[0]) * METRES_PER_CM).tolist()}))
        b.gltf["nodes"][joint_nodes[0]].setdefault("children", []).extend(eye_nodes)
        joint_rest = np.vstack([rest, centres])
    n_joints = len(joint_rest)
    ibm = np.tile(np.eye(4, dtype=np.float32), (n_joints, 1, 1))
    ibm[:, 3, :3] = -(joint_rest * METRES_PER_CM)  # column-major: translation in the last column
    skin = b.add("skins", {
        "name": f"{rig.name}_skin",
        "joints": joint_nodes + eye_nodes,
        "skeleton": root_node,
        "inverseBindMatrices": b.accessor(ibm.reshape(n_joints, 16), gltf_type="MAT4"),
    })
    b.gltf["nodes"][mesh_node]["skin"] = skin
    b.gltf["scenes"] = [{"name": rig.name or "face", "nodes": [mesh_node, root_node]}]
    b.gltf["scene"] = 0
    return {"mesh": mesh_node, "root": root_node, "joints": joint_nodes, "eyes": eye_nodes}


def _rig_extras(rig: FaceRig, textures: _Textures, n_region_chunks: int) -> dict:
    """``extras.capture2face``: the rest of the FaceRig, as JSON."""
    extras = {
        "format": EXTRAS_FORMAT,
        "name": rig.name,
        "cm_per_unit": CM_PER_METRE,
        "bone_names": list(rig.bone_names),
        "bone_rest_cm": _tolist(rig.bone_rest),
        "bone_parents": _tolist(rig.bone_parents),
        "bone_landmarks": _tolist(rig.bone_landmarks),
        "bone_groups": _tolist(rig.bone_groups),
        "landmark_vertices": _tolist(rig.landmark_vertices),
        "pose_names": list(rig.pose_names),
        "pose_bones_cm": _tolist(rig.pose_bones),
        "pose_morph_weights": _tolist(rig.pose_morph_weights),
        "pose_maps": _tolist(rig.pose_maps),
        "wrinkle_maps": [{"name": n, "image": i} for n, i in zip(rig.wrinkle_map_names, textures.wrinkle_images)],
        "zone_names": list(rig.zone_names),
        "zone_mask_images": textures.zone_images,
        "zone_table": _tolist(rig.zone_table),
        "region_names": list(rig.region_names),
        "region_attributes": [f"_REGIONS_{c}" for c in range(n_region_chunks)],
    }
    if rig.has_eyes:
        extras.update(eye_joints=list(EYE_JOINT_NAMES), eye_centres_cm=_tolist(rig.eye_centres))
    if rig.landmark_faces is not None and rig.landmark_bary is not None:  # landmarks on the surface
        extras.update(landmark_faces=_tolist(rig.landmark_faces), landmark_bary=_tolist(rig.landmark_bary))
    return extras


def build_rig_gltf(rig: FaceRig) -> tuple[GlbBuilder, dict]:
    """The glTF document of ``rig`` (no animation). Returns the builder and the node
    indices ``{"mesh": i, "root": j, "joints": [k0, k1, ...]}`` an animation targets."""
    _joint_order_check(rig)
    b = GlbBuilder()
    # The order of these steps is the order of the buffers, images and nodes in the file.
    groups = _alpha_groups(rig)
    geometry = _add_geometry(b, rig, groups)
    textures = _add_textures(b, rig, groups)
    mesh = _add_mesh(b, rig, geometry, textures.materials)
    nodes = _add_skeleton(b, rig, mesh)
    b.gltf["extras"] = {EXTRAS_KEY: _rig_extras(rig, textures, geometry.n_region_chunks)}
    return b, nodes


def export_glb(rig: FaceRig, path: str | os.PathLike, animation=None, fps: float | None = None) -> None:
    """Write ``rig`` as a .glb (atomically); with ``animation`` (an
    :class:`~capture2face.retarget.animation.Animation` of this rig) also one glTF
    animation: per-bone translation channels, a morph ``weights`` channel, the head
    rotation and the eye joints' rotations (gaze), sampled per frame. ``fps`` replaces the
    clip's timestamps by frame / fps."""
    builder, nodes = build_rig_gltf(rig)
    if animation is not None:
        add_animation(builder, rig, animation, nodes, fps=fps)
    write_bytes_atomic(path, builder.to_bytes())


def import_glb(path: str | os.PathLike, mapping_json: str | os.PathLike | None = None) -> FaceRig:
    """Read a character .glb (skin and/or morph targets) plus its mapping JSON into a
    FaceRig as the files give it (:mod:`capture2face.gltf.rig_import`; the JSON's schema:
    docs/characters.md). :func:`capture2face.character.load.import_glb` (also
    ``capture2face.import_glb``) adds what the default avatar lends a character."""
    return _import(path, mapping_json)

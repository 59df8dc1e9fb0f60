"""Import a user's character (.glb with a skin and/or morph targets) as a :class:`FaceRig`,
as the file and its mapping JSON give it; what the character lacks is not lent from
another character here (:func:`capture2face.character.load.import_glb` does that).

The passes, one module each (as Blender's ``io_scene_gltf2/blender/imp``):

1. :mod:`.mapping`: the mapping JSON, read and checked once (docs/characters.md, "The
   mapping JSON"); :mod:`.own_extras`: a .glb from :func:`capture2face.gltf.export_glb`
   carries the rest of its FaceRig in ``extras.capture2face`` and comes back complete.
2. :mod:`.scene`: world matrices and the nodes that draw a mesh (head, eyes, teeth, hair,
   body, glasses: every one is drawn).
3. :mod:`.skins`: the skeleton (the skins' joints united by node; bone 0 ``head`` is the
   mapping's ``head_bone``, else a joint named head in any case or prefix, else the neck,
   else a synthetic root) and each mesh's scene transform at its bind pose.
4. :mod:`.surface` over :mod:`.meshes`: every drawn mesh in scene space, one vertex array
   (primitives that share their POSITION share vertices); POSITION, NORMAL, TANGENT,
   TEXCOORD, JOINTS_0/1 + WEIGHTS_0/1; normals computed where missing (:mod:`.welding`).
5. :mod:`.skins` again: the 4 largest influences, renormalized; the head's weights (its
   joint's and those under it: eyes, jaw) become ``FaceRig.head_weights``.
6. :mod:`.morphs`: one FaceRig morph per name over every mesh that carries it, ARKit
   names matched in any spelling; NORMAL deltas carried like the rest normals, derived
   where missing (welded smooth normals of the morphed shape minus the rest's); a .vrm's
   expressions replace them (:mod:`.vrm`: one morph per expression, its binds summed; a
   VRM 0.x is turned to face +z).
7. :mod:`.textures` with :mod:`.materials`: albedo, alpha and normal map (one set, or an
   atlas of ``ATLAS_MAX`` px when the materials need textures of their own), alpha modes,
   wrinkle maps and zone masks.
8. :mod:`.mapped_rig`: bones tied to landmarks, groups, poses, zone table rows.

Units and axes: glTF's +y up / +z forward matches head coordinates; lengths are
multiplied by ``scale`` (default 100: glTF metres -> cm). Sparse accessors,
``byteStride``, normalized and quantized attributes are handled; any other required
extension is refused in one line naming it (:mod:`.container`). A .glb without skin and
morph targets, or an unreadable file, raises ``CaptureError``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import GlbReader
from capture2face.gltf.mapped_rig import apply_mapping
from capture2face.gltf.mapping import Mapping, check_mapped_morphs, load_mapping
from capture2face.gltf.materials import ALPHA_MODES, MATERIAL_CODES, double_sided, overlay_vertices
from capture2face.gltf.morphs import merge_morphs
from capture2face.gltf.own_extras import apply_own_extras, own_extras
from capture2face.gltf.scene import check_hierarchy, mesh_nodes, world_matrices
from capture2face.gltf.skins import head_weights, read_skeleton, skin_weights
from capture2face.gltf.surface import scene_surface
from capture2face.gltf.textures import ATLAS_MAX, DEFAULT_TEXTURE_SIZE, read_textures
from capture2face.gltf.vrm import VRM_EYE_BONES, expression_morphs, eye_bones, face_forward, look_ranges
from capture2face.gltf.welding import weld_ids
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES, FaceRig
from capture2face.topology import N_LANDMARKS

# The constants that lived here before the split, where they are now.
__all__ = ["ALPHA_MODES", "ATLAS_MAX", "DEFAULT_TEXTURE_SIZE", "MATERIAL_CODES", "N_LANDMARKS", "ImportedGlb",
           "import_glb", "read_glb"]


@dataclass(frozen=True)
class ImportedGlb:
    """A character file read: its rig, its mapping and whether it is our own export
    (whose rig is complete as it is)."""

    rig: FaceRig
    mapping: Mapping
    own_export: bool


def import_glb(path: str | os.PathLike, mapping_json: str | os.PathLike | None = None) -> FaceRig:
    """Read a character .glb (and its mapping JSON: ``mapping_json``, else the .glb's path
    with ``.json`` where it exists) into a FaceRig, as the files give it. See the module
    docs; :func:`capture2face.character.load.import_glb` adds what the default avatar lends."""
    return read_glb(path, mapping_json).rig


def read_glb(path: str | os.PathLike, mapping_json: str | os.PathLike | None = None) -> ImportedGlb:
    """:func:`import_glb`'s rig with the mapping it was read with."""
    glb = Path(path)
    r = GlbReader(glb)
    mapping = load_mapping(glb, mapping_json)
    ours = own_extras(r.gltf)
    try:
        rig = _build(r, glb, mapping, ours)
    except (KeyError, IndexError, TypeError) as exc:
        # A missing key, index or wrong JSON type in the file's own structure: its content
        # is malformed. (ValueError is not caught: our own NumPy bugs raise it too.)
        raise CaptureError(f"{glb}: malformed glTF content ({exc.__class__.__name__}: {exc})") from None
    return ImportedGlb(rig=rig, mapping=mapping, own_export=bool(ours))


def _scale(mapping: Mapping, ours: dict | None) -> float:
    """cm per glTF unit: the mapping's, else our export's, else 100 (metres)."""
    given = mapping.scale if mapping.scale is not None else (ours.get("cm_per_unit", 100.0) if ours else 100.0)
    scale = float(given)
    if not np.isfinite(scale) or scale <= 0:
        raise CaptureError(f"mapping: 'scale' must be a positive number, not {mapping.scale}")
    return scale


def _build(r: GlbReader, glb: Path, mapping: Mapping, ours: dict | None) -> FaceRig:
    """The import's passes (the module docs); then what the mapping (or our own extras) adds."""
    g = r.gltf
    face_forward(g)  # a VRM 0.x faces -z
    scale = _scale(mapping, ours)
    check_hierarchy(g.get("nodes", []), str(glb))
    picked = mesh_nodes(g, str(glb))
    skeleton = read_skeleton(r, picked, world_matrices(g.get("nodes", [])), mapping.head_bone)
    surface = scene_surface(r, picked, skeleton, mapping, scale)
    check_mapped_morphs(mapping, [n for p in surface.parts for n in p.morph_names])
    skin_joints, weights = skin_weights(surface.n_vertices, [(p.rows, p.bones, p.weights) for p in surface.parts])
    morphs, rules = expression_morphs(g, picked, surface.parts, merge_morphs(surface, mapping.arkit_renames()))
    tex = read_textures(r, surface.uvs, surface.gltf_material, surface.largest_material, mapping, ours)
    V, B, M = surface.n_vertices, len(skeleton.bone_names), len(morphs.names)
    rest = (skeleton.bone_rest * scale).astype(np.float32)
    names = tex.wrinkle_names
    eyes = eye_bones(g, skeleton.bone_nodes, rest, skin_joints, weights)  # a VRM's humanoid eyes
    rig = FaceRig(
        name=str(mapping.name or (ours or {}).get("name") or glb.stem),
        vertices=surface.vertices, normals=surface.normals.astype(np.float32), uvs=tex.uvs,
        tangents=surface.tangents.astype(np.float32), triangles=surface.triangles.astype(np.int32),
        position_ids=(surface.position_ids if surface.position_ids is not None
                      else weld_ids(surface.vertices)).astype(np.int32),
        material=surface.material.astype(np.uint8),
        landmark_vertices=np.full(N_LANDMARKS, -1, np.int32),
        bone_names=skeleton.bone_names, bone_rest=rest, bone_parents=skeleton.bone_parents,
        bone_landmarks=np.full(B, -1, np.int32), bone_groups=np.arange(B, dtype=np.int32),
        skin_joints=skin_joints, skin_weights=weights,
        morph_names=morphs.names, morph_positions=morphs.positions, morph_normals=morphs.normals,
        pose_names=["stretch", "compress"],
        pose_bones=np.repeat((skeleton.bone_rest * scale)[None], 2, 0).astype(np.float32),
        pose_morph_weights=np.zeros((2, M), np.float32),
        pose_maps=np.array([names.index("stretch"), names.index("compress")], np.int32)
        if {"stretch", "compress"} <= set(names) else np.zeros(2, np.int32),
        wrinkle_map_names=names, albedo=tex.albedo, normal_map=tex.normal_map,
        wrinkle_maps=tex.wrinkle_maps, zone_names=list(ZONE_NAMES), zone_masks=tex.zone_masks,
        zone_table=np.zeros((M, len(ZONE_NAMES)), np.float32),
        region_names=list(REGION_NAMES), region_weights=np.zeros((len(REGION_NAMES), V), np.float32),
        head_weights=head_weights(skin_joints, weights, skeleton),
        double_sided=double_sided(g, surface.gltf_material),
        alpha=tex.alpha, alpha_mode=tex.alpha_mode, alpha_cutoff=tex.alpha_cutoff,
        overlay_vertices=overlay_vertices(g, surface.gltf_material, surface.largest_material,
                                          [(ni, p.rows, p.tri_count) for ni, p in zip(picked, surface.parts)]),
        morph_rules=rules, normals_from_shape=not ours, look_ranges=look_ranges(g),
        eye_centres=None if eyes is None else eyes[0], eye_vertex_side=None if eyes is None else eyes[1],
        eye_source="" if eyes is None else VRM_EYE_BONES,
    )
    if ours:
        return apply_own_extras(rig.replace(head_weights=None), ours, surface)
    return apply_mapping(rig, mapping)

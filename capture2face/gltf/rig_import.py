"""Import a user's character (.glb with a skin and/or morph targets) as a :class:`FaceRig`.

What is read from the .glb: every node that draws a mesh (head, eyes, teeth, hair, body,
glasses), each in scene space (its node's world transform, or its skin's bind pose),
all merged into one vertex array (primitives of a mesh that share their POSITION share
vertices); POSITION, NORMAL, TANGENT, TEXCOORD_0, JOINTS_0/1 + WEIGHTS_0/1 (the 4 largest
influences kept, renormalized; the skins' joints united by node), morph targets
(POSITION and NORMAL deltas, names from ``mesh.extras.targetNames``): one FaceRig morph
per name over every mesh that carries it, ARKit names matched in any spelling
(:func:`~capture2face.rig.arkit_names.canonical_arkit`: ``eyeBlink_L`` on the head and
``eyeBlinkLeft`` on the eyes are one morph). NORMAL deltas are carried like the rest
normals (the node's or bind pose's inverse transpose, with the rest normal's own
normalising scale, so rest + sum w * delta normalised is glTF's morphed normal); a morph
without them gets them derived: the welded smooth normals of the morphed shape minus
those of the rest shape, exactly 0 wherever the morph leaves a vertex's triangles alone.
Textures: the albedo (baseColorTexture times baseColorFactor) and normal map
(normalTexture) of the largest primitive's material; when the drawn meshes need textures
of their own (different base-colour textures, or a MASK / BLEND material whose alpha
the largest's texture does not hold), every material's set packed into one atlas (a
grid of tiles of at most ``ATLAS_MAX`` px) with the UVs moved into their tile (UVs
outside [0, 1] are clamped, not tiled). Alpha: a MASK or BLEND material's base-colour
alpha (texture times factor) goes to ``FaceRig.alpha``, its mode and cutoff to each of
its vertices (``alpha_mode``, ``alpha_cutoff``); all None when every material is
opaque. A texture that cannot be read (a codec we lack, a missing file): the material
drawn with its base colour factor (or without its normal map), with a warning naming
the image. Sparse accessors, ``byteStride``, normalized and quantized
integer attributes (``KHR_mesh_quantization``) are handled; any other required
extension is refused in one line naming it (:mod:`capture2face.gltf.container`).
A .glb written by :func:`capture2face.gltf.export_glb` carries the rest of its
FaceRig in ``extras.capture2face`` and comes back complete.

**The head joint** (bone 0 ``head``): the mapping's ``head_bone``, else a joint named
head (any case or prefix, e.g. ``mixamorig:Head``), else the neck. Its skin weights and
those of the joints under it (eyes, jaw) become ``FaceRig.head_weights``: the head
rotation turns those vertices about the joint and leaves the body where it is.

**Units and axes**: glTF's +y up / +z forward matches head coordinates (+y up, +z out of
the face); lengths are multiplied by ``scale`` (default 100: glTF metres -> cm).

**The mapping JSON** (default: the .glb's path with ``.json``; every key optional; lengths
in cm in the character's frame, i.e. glTF axes after ``scale``; relative paths are
relative to the JSON file)::

    {
      "name": "my_character",
      "scale": 100.0,
      "head_bone": "Head",
      "bones": {"Brow_Inner_L": 336, "Brow_Inner_R": 107, "Jaw": 152},
      "bone_groups": [["Brow_Inner_L", "Brow_Inner_R"]],
      "landmark_vertices": {"33": 1043, "263": 2211},
      "materials": {"EyeMaterial": "eye", "MouthBag": "mouth", "Teeth": "teeth"},
      "wrinkle_maps": {"stretch": "maps/stretch_n.png", "compress": "maps/compress_n.png"},
      "poses": {
        "stretch":  {"offsets": {"Brow_Inner_L": [0, 0.8, 0.1]}, "wrinkle_map": "stretch",
                     "morphs": {"browInnerUp": 1.0}},
        "compress": {"positions": {"Brow_Inner_L": [1.1, 3.9, 5.0]}, "wrinkle_map": "compress"}
      },
      "zone_masks": ["maps/zones_0.png", "maps/zones_1.png"],
      "zone_table": {"browInnerUp": [-1, -1, 0, 0, 0, 0, 0, 0]},
      "morphs": {"Fcl_MTH_A": "jawOpen", "Fcl_EYE_Close_L": "eyeBlinkLeft"}
    }

* ``materials``: material name -> "skin", "eye", "mouth" (the dark mouth cavity),
  "teeth" (teeth and tongue) or "hair" (lashes, brows, hair cards: shaded as skin, not
  the face); unnamed ones are guessed from the material's name (lash, brow, hair, ...
  -> hair; eye, iris, ... -> eye; teeth, tooth, tongue -> teeth; mouth, gum -> mouth;
  else skin).
* ``head_bone``: the joint that becomes bone 0 ``head`` (default: a joint named ``head``,
  else a synthetic root bone that takes the weight nothing else has).
* ``bones``: joint name -> MediaPipe landmark index (0-477) the bone follows.
* ``poses``: per reference pose either ``offsets`` (from the rest position) or absolute
  ``positions`` of some bones (others stay at rest), the wrinkle map it shows, and the morph
  weights that go with it.
* ``wrinkle_maps``: tangent-space normal maps (PNG/JPEG, any size; resized to the albedo's).
* ``zone_masks``: two RGBA images, the 8 zones in the order of ``ZONE_NAMES``.
* ``zone_table``: morph name -> 8 zone weights (Oat's sign: +1 compress, -1 stretch).
* ``morphs``: morph name -> the ARKit blendshape it is (``{"Fcl_MTH_A": "jawOpen"}``),
  for names that do not spell one.

**Defaults for what is missing**: normals and tangents computed; flat normal map and
flat "stretch"/"compress" wrinkle maps; zone masks zero; a mid skin tone albedo. When
bones are tied to landmarks, the default avatar is fitted to them (similarity transform
of its landmarks onto the bones' rest positions) and lends what the character lacks:
reference poses (its bone offsets for the same landmarks, scaled by face size), zone
table rows (by morph name), region weights and tracker landmark vertices (nearest
vertices to its fitted landmarks). Without any bone landmarks those stay empty (zero
regions, no poses' motion, landmark vertices -1): an ARKit morph character is then driven
by the clip's ARKit curves (:func:`capture2face.rig.arkit_names.drive_mode`); a character
with tracker landmark vertices from the mapping gets a warning that nothing was lent.

A .glb without skin and morph targets, or an unreadable file, raises ``CaptureError``.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from capture2face.errors import CaptureError
from capture2face.gltf.container import (
    EXTRAS_FORMAT,
    EXTRAS_KEY,
    GlbReader,
    decode_image,
    texture_transform,
)
from capture2face.gltf.mapping import check_mapping
from capture2face.maths.rotations import similarity
from capture2face.rig.arkit_names import arkit_morphs, canonical_arkit
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES, FaceRig
from capture2face.rig.mesh_ops import uv_tangents, vertex_normals
from capture2face.runtime.log import log

N_LANDMARKS = 478
DEFAULT_TEXTURE_SIZE = 256
MATERIAL_CODES = {"skin": 0, "eye": 1, "mouth": 2, "teeth": 3, "hair": 4}
# Lashes, brows and hair cards: drawn as skin, not as an eye (no glossy highlight on
# lashes named "EyeLashes"), never the face's skin (no landmarks, no wrinkles).
_HAIR_WORDS = ("lash", "brow", "hair", "beard", "moustache", "mustache")
_EYE_WORDS = ("eye", "iris", "cornea", "sclera", "pupil")
_TEETH_WORDS = ("teeth", "tooth", "tongue")
_MOUTH_WORDS = ("mouth", "gum")


# ---- node transforms ------------------------------------------------------------------
def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _local_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(node.get("rotation", [0, 0, 0, 1])) * np.asarray(node.get("scale", [1, 1, 1]))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _world_matrices(nodes: list[dict]) -> list[np.ndarray]:
    parent = {c: p for p, n in enumerate(nodes) for c in n.get("children", [])}
    cache: dict[int, np.ndarray] = {}

    def world(i: int) -> np.ndarray:
        if i not in cache:
            local = _local_matrix(nodes[i])
            cache[i] = world(parent[i]) @ local if i in parent else local
        return cache[i]

    return [world(i) for i in range(len(nodes))]


# ---- mapping file ---------------------------------------------------------------------
def _load_mapping(glb: Path, mapping_json) -> tuple[dict, Path]:
    path = Path(mapping_json) if mapping_json else glb.with_suffix(".json")
    if not path.is_file():
        if mapping_json:
            raise CaptureError(f"{path}: mapping file not found")
        return {}, glb.parent
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureError(f"{path}: not a readable mapping JSON ({exc})") from None
    check_mapping(data, path)  # the schema (capture2face.gltf.mapping), before anything is imported
    return data, path.parent


def _read_image_file(path: Path) -> np.ndarray:
    try:
        return decode_image(path.read_bytes())
    except (OSError, ValueError):
        raise CaptureError(f"{path}: image not found or unreadable") from None


def _fit(image: np.ndarray, size: tuple[int, int], channels: int = 3) -> np.ndarray:
    """Resize (H, W) and keep ``channels`` channels (alpha dropped, grey expanded)."""
    if image.shape[2] < channels:
        image = np.concatenate([image, np.zeros(image.shape[:2] + (channels - image.shape[2],), np.uint8)], 2)
    image = np.ascontiguousarray(image[:, :, :channels])
    if image.shape[:2] != size:
        image = cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_AREA)
        if image.ndim == 2:
            image = image[:, :, None]
    return image


# ---- mesh gathering -------------------------------------------------------------------
def _mesh_nodes(g: dict, path: str) -> list[int]:
    """Every node that draws a mesh (hair, body, glasses, eyes, teeth: all of the
    character is drawn), in node order; at least one of them skinned or with morphs."""
    nodes = g.get("nodes", [])
    meshes = g.get("meshes", [])
    drawn = [i for i, n in enumerate(nodes) if isinstance(n.get("mesh"), int) and 0 <= n["mesh"] < len(meshes)
             and any(p.get("mode", 4) in (4, 5, 6) and "POSITION" in p.get("attributes", {})
                     for p in meshes[n["mesh"]].get("primitives", []))]
    if not any("skin" in nodes[i] or any(p.get("targets") for p in meshes[nodes[i]["mesh"]]["primitives"])
               for i in drawn):
        raise CaptureError(f"{path}: the .glb has no skinned mesh and no morph targets; nothing to animate")
    return drawn


def _triangles(r: GlbReader, prim: dict, n_vertices: int) -> np.ndarray:
    idx = r.accessor(prim["indices"], as_float=False)[:, 0].astype(np.int64) if "indices" in prim \
        else np.arange(n_vertices)
    mode = prim.get("mode", 4)
    if mode == 4:
        tris = idx[: len(idx) // 3 * 3].reshape(-1, 3)
    elif mode == 5:  # strip: alternate winding
        k = np.arange(len(idx) - 2)
        tris = np.stack([idx[k], idx[k + 1 + (k % 2)], idx[k + 2 - (k % 2)]], 1)
    elif mode == 6:  # fan
        k = np.arange(1, len(idx) - 1)
        tris = np.stack([np.full_like(k, idx[0]), idx[k], idx[k + 1]], 1)
    else:
        return np.zeros((0, 3), np.int64)
    if tris.size and tris.max() >= n_vertices:
        raise CaptureError(f"{r.path}: a primitive's indices point past its vertices")
    return tris


def _material_code(g: dict, prim: dict, mapping: dict, mesh_name: str = "") -> int:
    """0 skin, 1 eye, 2 mouth, 3 teeth, 4 hair: the mapping's word for the material, else
    its name's, else the mesh's name's (characters often share one material between face,
    eyes and teeth, in meshes named after them)."""
    name = str(g.get("materials", [])[prim["material"]].get("name", "")) if "material" in prim else ""
    given = mapping.get("materials", {})
    if name in given:
        code = MATERIAL_CODES.get(str(given[name]).lower())
        if code is None:
            raise CaptureError(f"mapping: material '{name}' must be one of {sorted(MATERIAL_CODES)}")
        return code
    for text in (name.lower(), str(mesh_name).lower()):
        if any(w in text for w in _HAIR_WORDS):
            return 4
        if any(w in text for w in _EYE_WORDS):
            return 1
        if any(w in text for w in _TEETH_WORDS):
            return 3
        if any(w in text for w in _MOUTH_WORDS):
            return 2
    return 0


def _counted(r: GlbReader, values: np.ndarray, n: int, what: str) -> np.ndarray:
    """``values`` when it has one row per vertex; a malformed file otherwise."""
    if len(values) != n:
        raise CaptureError(f"{r.path}: {what} has {len(values)} values for {n} vertices")
    return values


def _target_names(mesh: dict, n_targets: int) -> list[str]:
    names = mesh.get("extras", {}).get("targetNames") or \
        next((p.get("extras", {}).get("targetNames") for p in mesh.get("primitives", [])
              if p.get("extras", {}).get("targetNames")), None)
    out = [str(n) for n in names][:n_targets] if names else []
    return out + [f"target_{i}" for i in range(len(out), n_targets)]


def _primitive_blocks(r: GlbReader, mesh: dict, mapping: dict) -> tuple[dict[int, dict], list[int], int | None]:
    """The mesh's triangle primitives grouped by their POSITION accessor: per accessor its
    first primitive, vertex count, triangles, per-vertex material codes and glTF
    materials, and triangle count. Returns the blocks, their accessors in first-seen
    order, and the number of morph targets (the same on every primitive)."""
    g = r.gltf
    blocks: dict[int, dict] = {}
    order: list[int] = []
    n_targets = None
    for prim in mesh.get("primitives", []):
        attrs = prim.get("attributes", {})
        if "POSITION" not in attrs or prim.get("mode", 4) not in (4, 5, 6):
            continue
        key = attrs["POSITION"]
        pos = r.accessor(key).astype(np.float64)
        if key not in blocks:
            order.append(key)
            blocks[key] = {"prim": prim, "n": len(pos), "tris": [], "material": np.zeros(len(pos), np.uint8),
                           "gltf_material": np.full(len(pos), -1, np.int64), "tri_count": 0, "uv_parts": []}
        blk = blocks[key]
        tris = _triangles(r, prim, len(pos))
        blk["tris"].append(tris)
        code = _material_code(g, prim, mapping, mesh.get("name", ""))
        used = np.unique(tris)
        blk["uv_parts"].append((prim, used))
        if code:
            blk["material"][used] = code
        blk["gltf_material"][used] = prim.get("material", -1)
        blk["tri_count"] += len(tris)
        nt = len(prim.get("targets", []))
        if n_targets is not None and nt != n_targets:
            raise CaptureError(f"{r.path}: the mesh's primitives have different numbers of morph targets")
        n_targets = nt
    if not order:
        raise CaptureError(f"{r.path}: the mesh has no triangle primitives")
    return blocks, order, n_targets


def _attribute(r: GlbReader, prim: dict, name: str, as_float: bool = True) -> np.ndarray | None:
    """A vertex attribute of ``prim`` (one row per vertex), or None when it has none."""
    if name in prim.get("attributes", {}):
        return _counted(r, r.accessor(prim["attributes"][name], as_float=as_float), len(
            r.accessor(prim["attributes"]["POSITION"])), name)
    return None


def _texture_uvs(r: GlbReader, blk: dict) -> np.ndarray | None:
    """(n, 2) UVs of a block as its base colour textures sample them: per primitive, the
    texture's coordinate set with its ``KHR_texture_transform`` applied (gltfpack's
    quantized UVs rely on it) at the vertices the primitive draws; TEXCOORD_0 as stored
    where a primitive has no base colour texture."""
    uv = _attribute(r, blk["prim"], "TEXCOORD_0")
    materials = r.gltf.get("materials", [])
    for prim, used in blk["uv_parts"]:
        mat = materials[prim["material"]] if "material" in prim else {}
        info = (mat.get("pbrMetallicRoughness") or {}).get("baseColorTexture")
        if not info:
            continue
        tex_coord, m = texture_transform(info)
        src = _attribute(r, prim, f"TEXCOORD_{tex_coord}")
        if src is None:
            continue
        uv = np.array(src, np.float64) if uv is None else np.array(uv, np.float64)
        uv[used] = src[used].astype(np.float64) @ m[:, :2].T + m[:, 2]
    return uv


def _block_arrays(r: GlbReader, key: int, blk: dict, offset: int) -> dict:
    """One block's vertex arrays (None where its primitive lacks the attribute), its
    triangles shifted by ``offset``, and its morph target deltas."""
    prim, n = blk["prim"], blk["n"]
    out = {"pos": r.accessor(key).astype(np.float64)}
    out["nrm"] = _attribute(r, prim, "NORMAL")
    out["uv"] = _texture_uvs(r, blk)
    out["tan"] = _attribute(r, prim, "TANGENT")
    j = [_attribute(r, prim, f"JOINTS_{s}", as_float=False) for s in range(2)]
    w = [_attribute(r, prim, f"WEIGHTS_{s}") for s in range(2)]
    pairs = [(jj, ww) for jj, ww in zip(j, w) if jj is not None and ww is not None]
    out["joints"] = np.concatenate([p[0] for p in pairs], 1).astype(np.int64) if pairs else None
    out["weights"] = np.concatenate([p[1] for p in pairs], 1).astype(np.float32) if pairs else None
    out["tris"] = np.concatenate(blk["tris"]) + offset
    mat = _attribute(r, prim, "_MATERIAL")
    out["material"] = np.rint(mat[:, 0]).astype(np.uint8) if mat is not None else blk["material"]
    out["gltf_material"] = blk["gltf_material"]
    pid = _attribute(r, prim, "_POSITION_ID")
    out["posid"] = None if pid is None else np.rint(pid[:, 0]).astype(np.int64)
    chunks = []
    c = 0
    while f"_REGIONS_{c}" in prim.get("attributes", {}):
        chunks.append(_attribute(r, prim, f"_REGIONS_{c}"))
        c += 1
    out["regions"] = np.concatenate(chunks, 1) if chunks else None
    targets = prim.get("targets", [])
    out["mpos"] = np.stack([_counted(r, r.accessor(t["POSITION"]), n, "a morph target").astype(np.float64)
                            if "POSITION" in t
                            else np.zeros((n, 3)) for t in targets]) if targets else np.zeros((0, n, 3))
    out["mnrm"] = np.stack([_counted(r, r.accessor(t["NORMAL"]), n, "a morph target").astype(np.float64)
                            if "NORMAL" in t
                            else np.full((n, 3), np.nan) for t in targets]) if targets else np.zeros((0, n, 3))
    return out


def _merge_blocks(out: dict[str, list], sizes: list[int], blocks: list[dict], mesh: dict, n_targets: int | None) -> dict:
    """The blocks' arrays concatenated into one vertex array; an attribute some blocks
    lack is filled (NaN normals and tangents, zero UVs, joints and weights), one that
    none has is None."""

    def cat(name, width, fill):
        parts = out[name]
        if all(p is None for p in parts):
            return None
        return np.concatenate([p if p is not None else np.full((n, width), fill) for p, n in zip(parts, sizes)])

    merged = {
        "pos": np.concatenate(out["pos"]),
        "tris": np.concatenate(out["tris"]).astype(np.int64),
        "material": np.concatenate(out["material"]),
        "gltf_material": np.concatenate(out["gltf_material"]),
        "mpos": np.concatenate(out["mpos"], axis=1),
        "mnrm": np.concatenate(out["mnrm"], axis=1),
        "nrm": cat("nrm", 3, np.nan), "uv": cat("uv", 2, 0.0), "tan": cat("tan", 4, np.nan),
        "largest_material": max(blocks, key=lambda b: b["tri_count"])["prim"].get("material"),
        "tri_count": sum(b["tri_count"] for b in blocks),
        "target_names": _target_names(mesh, n_targets or 0),
    }
    widths = [p.shape[1] for p in out["joints"] if p is not None]
    width = max(widths) if widths else 0
    if width:
        merged["joints"] = np.concatenate([np.pad(p, ((0, 0), (0, width - p.shape[1]))) if p is not None
                                           else np.zeros((n, width), np.int64) for p, n in zip(out["joints"], sizes)])
        merged["weights"] = np.concatenate([np.pad(p, ((0, 0), (0, width - p.shape[1]))) if p is not None
                                            else np.zeros((n, width), np.float32) for p, n in zip(out["weights"], sizes)])
    else:
        merged["joints"] = merged["weights"] = None
    merged["posid"] = None if any(p is None for p in out["posid"]) else np.concatenate(out["posid"])
    merged["regions"] = None if any(p is None for p in out["regions"]) else np.concatenate(out["regions"])
    merged["n_vertices"] = len(merged["pos"])
    return merged


def _gather(r: GlbReader, mesh: dict, mapping: dict) -> dict:
    """Merge one mesh's primitives (in the mesh's own space): primitives that share their
    POSITION accessor share vertices; every other primitive appends its own."""
    blocks, order, n_targets = _primitive_blocks(r, mesh, mapping)
    out = {k: [] for k in ("pos", "nrm", "uv", "tan", "joints", "weights", "tris", "material",
                           "posid", "regions", "mpos", "mnrm", "gltf_material")}
    offset = 0
    for key in order:
        for name, value in _block_arrays(r, key, blocks[key], offset).items():
            out[name].append(value)
        offset += blocks[key]["n"]
    return _merge_blocks(out, [blocks[k]["n"] for k in order], [blocks[k] for k in order], mesh, n_targets)


# ---- the import -----------------------------------------------------------------------
def import_glb(path: str | os.PathLike, mapping_json: str | os.PathLike | None = None) -> FaceRig:
    """Read a character .glb (and its mapping JSON) into a FaceRig. See the module docs."""
    glb = Path(path)
    r = GlbReader(glb)
    g = r.gltf
    mapping, mapping_dir = _load_mapping(glb, mapping_json)
    ours = g.get("extras", {}).get(EXTRAS_KEY) if isinstance(g.get("extras"), dict) else None
    if ours is not None and ours.get("format") != EXTRAS_FORMAT:
        ours = None
    if ours and ours.get("eye_joints"):
        # Our eye joints (the skin's last joints) turn the eyeballs; they are no bones.
        for skin in g.get("skins", []):
            skin["joints"] = skin["joints"][: len(ours["bone_names"])]
    try:
        return _build(r, glb, mapping, mapping_dir, ours)
    except (KeyError, IndexError, TypeError) as exc:
        # A missing key, index or wrong JSON type in the file's own structure: its content
        # is malformed. (ValueError is not caught: our own NumPy bugs raise it too.)
        raise CaptureError(f"{glb}: malformed glTF content ({exc.__class__.__name__}: {exc})") from None


def _build(r: GlbReader, glb: Path, mapping: dict, mapping_dir: Path, ours: dict | None) -> FaceRig:
    """The import's steps: skeleton, surface (every drawn mesh in scene space), skin,
    morphs, textures; then what the mapping (or our own extras) adds."""
    g = r.gltf
    scale = float(mapping.get("scale", ours.get("cm_per_unit", 100.0) if ours else 100.0))
    if not np.isfinite(scale) or scale <= 0:
        raise CaptureError(f"mapping: 'scale' must be a positive number, not {mapping.get('scale')}")
    picked = _mesh_nodes(g, str(glb))
    world = _world_matrices(g.get("nodes", []))
    skel = _skeleton(r, picked, world, mapping)
    surf = _surface(r, picked, world, skel, mapping, scale)
    skin_joints, skin_weights = _skin(surf, skel)
    morph_names, morph_positions, morph_normals = _morphs(surf, mapping, scale)
    tex = _textures(r, surf, mapping, mapping_dir, ours)
    V, B, M = len(surf["vertices"]), len(skel["bone_names"]), len(morph_names)
    vertices = surf["vertices"]
    wrinkle_names = tex["wrinkle_names"]
    rig = FaceRig(
        name=str(mapping.get("name") or (ours or {}).get("name") or glb.stem),
        vertices=vertices, normals=surf["normals"].astype(np.float32), uvs=tex["uvs"],
        tangents=surf["tangents"].astype(np.float32), triangles=surf["tris"].astype(np.int32),
        position_ids=(surf["posid"] if surf["posid"] is not None else _weld(vertices)).astype(np.int32),
        material=surf["material"].astype(np.uint8),
        landmark_vertices=np.full(N_LANDMARKS, -1, np.int32),
        bone_names=skel["bone_names"], bone_rest=(skel["bone_rest"] * scale).astype(np.float32),
        bone_parents=skel["bone_parents"],
        bone_landmarks=np.full(B, -1, np.int32), bone_groups=np.arange(B, dtype=np.int32),
        skin_joints=skin_joints, skin_weights=skin_weights,
        morph_names=morph_names, morph_positions=morph_positions, morph_normals=morph_normals,
        pose_names=["stretch", "compress"],
        pose_bones=np.repeat((skel["bone_rest"] * scale)[None], 2, 0).astype(np.float32),
        pose_morph_weights=np.zeros((2, M), np.float32),
        pose_maps=np.array([wrinkle_names.index("stretch"), wrinkle_names.index("compress")], np.int32)
        if {"stretch", "compress"} <= set(wrinkle_names) else np.zeros(2, np.int32),
        wrinkle_map_names=wrinkle_names, albedo=tex["albedo"], normal_map=tex["normal_map"],
        wrinkle_maps=np.stack(tex["wrinkle_maps"]), zone_names=list(ZONE_NAMES), zone_masks=tex["zone_masks"],
        zone_table=np.zeros((M, len(ZONE_NAMES)), np.float32),
        region_names=list(REGION_NAMES), region_weights=np.zeros((len(REGION_NAMES), V), np.float32),
        head_weights=_head_weights(skin_joints, skin_weights, skel),
        double_sided=_double_sided(r.gltf, surf),
        alpha=tex["alpha"], alpha_mode=None if tex["alpha_modes"] is None else tex["alpha_modes"][0],
        alpha_cutoff=None if tex["alpha_modes"] is None else tex["alpha_modes"][1],
        overlay_vertices=_overlays(g, picked, surf),
    )
    if ours:
        return _apply_ours(rig.replace(head_weights=None), ours, surf)
    return _apply_mapping(rig, mapping)


def _double_sided(g: dict, surf: dict) -> bool:
    """Whether any drawn material is double-sided (the whole character is then drawn
    without culling: one draw call); a primitive without a material is single-sided."""
    materials = g.get("materials", [])
    return any(bool(materials[int(i)].get("doubleSided", False)) for i in np.unique(surf["gltf_material"]) if i >= 0)


_OVERLAY_WORDS = ("lash", "brow", "hair", "glass", "lens", "beard", "fur")


def _overlays(g: dict, picked: list[int], surf: dict) -> np.ndarray | None:
    """(V,) bool: vertices of see-through overlays in front of the face that landmarks must
    not land on (alpha MASK / BLEND materials: lash and hair cards, glass; meshes or
    materials named lash, brow, hair, glass...), or None where there are none. The material
    and the mesh with the most triangles (the skin, whatever its name or alpha mode) never."""
    materials = g.get("materials", [])
    see_through = np.array([str(m.get("alphaMode", "OPAQUE")).upper() in ("MASK", "BLEND")
                            or any(w in str(m.get("name", "")).lower() for w in _OVERLAY_WORDS)
                            for m in materials] + [False], bool)  # index -1: no material
    if surf["largest_material"] is not None:
        see_through[int(surf["largest_material"])] = False
    out = see_through[surf["gltf_material"]]
    largest = max(range(len(picked)), key=lambda k: surf["parts"][k]["tri_count"])
    for k, (ni, part) in enumerate(zip(picked, surf["parts"])):
        name = str(g["meshes"][g["nodes"][ni]["mesh"]].get("name", "")).lower()
        if k != largest and any(w in name for w in _OVERLAY_WORDS):
            out[part["offset"]:part["offset"] + len(part["pos"])] = True
    return out if out.any() else None


# ---- skeleton -------------------------------------------------------------------------
_NOT_HEAD = ("top", "end", "nub", "tip", "eye", "jaw", "hair")


def _find_head(joint_names: list[str], mapping: dict) -> int | None:
    """The skin joint that becomes bone 0 ``head``: the mapping's ``head_bone``, else a
    joint called head (any case, any prefix such as ``mixamorig:Head``), else the neck."""
    head_name = mapping.get("head_bone")
    if head_name is not None:
        if head_name not in joint_names:
            raise CaptureError(f"mapping: head_bone '{head_name}' is not a joint of the skin")
        return joint_names.index(head_name)
    bare = [n.lower().rsplit(":", 1)[-1].rsplit("|", 1)[-1] for n in joint_names]
    for want in ("head", "neck"):
        exact = [k for k, n in enumerate(bare) if n == want]
        if exact:
            return exact[0]
        loose = [k for k, n in enumerate(bare) if want in n and not any(w in n for w in _NOT_HEAD)]
        if loose:
            return loose[0]
    return None


def _skeleton(r: GlbReader, picked: list[int], world: list[np.ndarray], mapping: dict) -> dict:
    """FaceRig bones = head + every joint of the drawn meshes' skins (their union, by
    node), rest positions at the bind pose (glTF units, scene space), parents, and the
    head's subtree (the joints a head rotation turns)."""
    g = r.gltf
    nodes = g.get("nodes", [])
    joints: list[int] = []  # node index per skin joint, union over skins
    bind: dict[int, np.ndarray] = {}  # joint node -> bind-pose world matrix
    node_joint_map: dict[int, np.ndarray] = {}  # mesh node -> its skin's joint k -> union index
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
    joint_names = [str(nodes[j].get("name", f"joint_{k}")) for k, j in enumerate(joints)]
    head_k = _find_head(joint_names, mapping) if joints else None
    if head_k is None and mapping.get("head_bone") is not None:
        raise CaptureError(f"mapping: head_bone '{mapping['head_bone']}' is not a joint of the skin")
    # bone b <- union joint order[b] (None = a synthetic head)
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
    parent_of = {c: p for p, n in enumerate(nodes) for c in n.get("children", [])}
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
    return {"bone_names": bone_names, "bone_rest": bone_rest, "bone_parents": bone_parents,
            "joint_to_bone": joint_to_bone, "node_joint_map": node_joint_map, "node_to_scene": node_to_scene,
            "has_head_joint": head_k is not None, "head_subtree": head_subtree, "n_joints": len(joints)}


# ---- surface --------------------------------------------------------------------------
def _surface(r: GlbReader, picked: list[int], world, skel: dict, mapping: dict, scale: float) -> dict:
    """Every drawn mesh in scene space, one vertex array: positions (cm), normals,
    tangents, UVs, triangles, material codes, skin joints (as bones) and weights, morph
    deltas with their names per mesh."""
    g = r.gltf
    nodes = g["nodes"]
    parts = []
    offset = 0
    for ni in picked:
        m = _gather(r, g["meshes"][nodes[ni]["mesh"]], mapping)
        to_scene = skel["node_to_scene"][ni]
        lin = to_scene[:3, :3]
        normal_rows = np.linalg.inv(lin)  # normals as rows: (inv(lin)^T n)^T = n^T inv(lin)
        pos = m["pos"] @ lin.T + to_scene[:3, 3]
        weld = _welding(pos, m["tris"])
        if m["nrm"] is not None and np.isfinite(m["nrm"]).all():
            normals = m["nrm"] @ normal_rows
        else:
            computed = _welded_normals(pos, weld)
            normals = computed if m["nrm"] is None else np.where(np.isfinite(m["nrm"]), m["nrm"] @ normal_rows, computed)
        # A file's NORMAL deltas go through the same transform and the same normalising scale.
        normal_scale = 1.0 / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        normals = normals * normal_scale
        uvs = m["uv"] if m["uv"] is not None else np.zeros((len(pos), 2))
        if m["tan"] is not None and np.isfinite(m["tan"]).all():
            t = m["tan"][:, :3] @ lin.T
            tangents = np.concatenate([t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12),
                                       np.where(m["tan"][:, 3:] < 0, -1.0, 1.0) * np.sign(np.linalg.det(lin))], 1)
        else:
            tangents = uv_tangents(pos, normals, uvs.astype(np.float64), m["tris"])
        bones = None
        if m["joints"] is not None and ni in skel["node_joint_map"]:
            remap = skel["node_joint_map"][ni]
            bones = skel["joint_to_bone"][remap[np.clip(m["joints"], 0, len(remap) - 1)]]
        mnrm = _morph_normal_deltas(m["mnrm"] @ normal_rows * normal_scale, m["mpos"] @ lin.T, pos, weld)
        parts.append({
            "pos": pos * scale, "normals": normals, "tangents": tangents, "uv": uvs, "tris": m["tris"] + offset,
            "material": m["material"], "gltf_material": m["gltf_material"], "bones": bones, "weights": m["weights"],
            "joints": m["joints"],  # the file's own JOINTS_0 (our export's eye joints are no bones)
            "posid": m["posid"], "regions": m["regions"], "mpos": m["mpos"] @ lin.T * scale, "mnrm": mnrm,
            "names": m["target_names"], "largest_material": m["largest_material"], "tri_count": m["tri_count"],
            "offset": offset,
        })
        offset += len(pos)
    # Tangents where UVs are degenerate and the normal is parallel to the fallback axis:
    # any perpendicular will do, take one from the x axis.
    normals = np.concatenate([p["normals"] for p in parts])
    tangents = np.concatenate([p["tangents"] for p in parts])
    bad = ~(np.linalg.norm(tangents[:, :3], axis=1) > 0.5)
    if bad.any():
        alt = np.cross(normals[bad], np.array([1.0, 0.0, 0.0]))
        tangents[bad, :3] = alt / np.maximum(np.linalg.norm(alt, axis=1, keepdims=True), 1e-12)
        tangents[bad, 3] = 1.0
    single = len(parts) == 1
    return {
        "parts": parts, "n_vertices": offset,
        "vertices": np.concatenate([p["pos"] for p in parts]).astype(np.float32),
        "normals": normals, "tangents": tangents,
        "uv": np.concatenate([p["uv"] for p in parts]).astype(np.float64),
        "tris": np.concatenate([p["tris"] for p in parts]),
        "material": np.concatenate([p["material"] for p in parts]),
        "gltf_material": np.concatenate([p["gltf_material"] for p in parts]),
        # What only our own (single-mesh) export has: vertex ids, regions, raw skin indices.
        "posid": parts[0]["posid"] if single else None,
        "regions": parts[0]["regions"] if single else None,
        "joints": parts[0]["joints"] if single else None,
        "weights": parts[0]["weights"] if single else None,
        "largest_material": max(parts, key=lambda p: p["tri_count"])["largest_material"],
    }


def _welding(pos: np.ndarray, tris: np.ndarray) -> dict:
    """One mesh's vertices welded by position (UV seams closed): ``ids`` (n,) weld id of
    each vertex, ``first`` (W,) a vertex of each id, ``tris`` (T, 3) over weld ids."""
    ids = _weld(pos)
    first = np.unique(ids, return_index=True)[1]
    return {"ids": ids, "first": first, "tris": ids[tris]}


def _welded_normals(pos: np.ndarray, weld: dict) -> np.ndarray:
    """(n, 3) smooth unit normals of positions ``pos`` (n, 3), welded (no seam at UV splits)."""
    return vertex_normals(pos[weld["first"]], weld["tris"])[weld["ids"]]


def _morph_normal_deltas(given: np.ndarray, deltas: np.ndarray, pos: np.ndarray, weld: dict) -> np.ndarray:
    """(K, n, 3) normal deltas of one mesh's K morphs in scene space: the file's NORMAL
    deltas (``given``, NaN where it has none), else derived from the position deltas
    ``deltas`` (K, n, 3) at rest positions ``pos`` (n, 3): the welded smooth normals of the
    morphed shape minus those of the rest shape, computed the same way, so they cancel
    wherever the morph leaves a vertex's triangles alone; the delta is exactly 0 there."""
    out = np.array(given, np.float64)
    missing = ~np.isfinite(out).all(axis=(1, 2))
    if not missing.any():
        return out
    ids, wtris = weld["ids"], weld["tris"]
    n_weld = len(weld["first"])
    rest = vertex_normals(pos[weld["first"]], wtris)
    for k in np.flatnonzero(missing):
        moved = np.zeros(n_weld, bool)
        moved[ids[np.abs(deltas[k]).max(axis=1) > 0]] = True
        touched = np.zeros(n_weld, bool)  # every vertex of a triangle that moved
        touched[wtris[moved[wtris].any(axis=1)]] = True
        derived = np.zeros((n_weld, 3))
        if touched.any():
            morphed = vertex_normals((pos + deltas[k])[weld["first"]], wtris)
            derived[touched] = morphed[touched] - rest[touched]
        out[k] = np.where(np.isfinite(out[k]), out[k], derived[ids])
    return out


# ---- skin -----------------------------------------------------------------------------
def _skin(surf: dict, skel: dict) -> tuple[np.ndarray, np.ndarray]:
    """(V, 4) bones and convex weights: the 4 largest influences, renormalized; vertices
    of unskinned meshes (and weightless ones) hang on bone 0."""
    V = surf["n_vertices"]
    skin_joints = np.zeros((V, 4), np.int32)
    skin_weights = np.zeros((V, 4), np.float32)
    skin_weights[:, 0] = 1.0
    for p in surf["parts"]:
        if p["bones"] is None:
            continue
        jb = p["bones"]
        w = np.clip(np.nan_to_num(p["weights"].astype(np.float32)), 0.0, None)
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
        rows = slice(p["offset"], p["offset"] + len(jb))
        skin_joints[rows], skin_weights[rows] = jb, w
    return skin_joints, skin_weights


def _head_weights(skin_joints: np.ndarray, skin_weights: np.ndarray, skel: dict) -> np.ndarray | None:
    """(V,) how much of the head rotation each vertex takes: its skin weights on the head
    joint and the joints below it (eyes, jaw); None without a head joint (the whole
    character turns)."""
    if not skel["has_head_joint"] or skel["n_joints"] < 2:
        return None
    return (skin_weights * skel["head_subtree"][skin_joints]).sum(1).astype(np.float32)


# ---- morphs ---------------------------------------------------------------------------
def _morph_key(name: str, renames: dict) -> tuple[str, str]:
    """(merge key, rig name) of a morph: the mapping's ARKit name, else the ARKit name it
    spells (any case or side suffix) with the character's own spelling, else itself."""
    if name in renames:
        return renames[name], renames[name]
    arkit = canonical_arkit(name)
    return (arkit, name) if arkit is not None else (name, name)


def _morphs(surf: dict, mapping: dict, scale: float) -> tuple[list[str], np.ndarray, np.ndarray]:
    """One morph per name over all meshes: every mesh that carries a morph of that name
    (head, eyes, teeth) gets its deltas in the rig's morph of the name (ARKit names
    matched with their variants, :func:`~capture2face.rig.arkit_names.canonical_arkit`)."""
    renames = mapping.get("morphs", {})
    if not isinstance(renames, dict):
        raise CaptureError("mapping: 'morphs' must map morph names to ARKit names")
    for src, dst in renames.items():
        if canonical_arkit(str(dst)) is None:
            raise CaptureError(f"mapping: morphs['{src}'] = '{dst}' is not an ARKit blendshape name")
    renames = {str(k): canonical_arkit(str(v)) for k, v in renames.items()}
    keys: dict[str, int] = {}
    names: list[str] = []
    slots = []
    for p in surf["parts"]:
        slot = []
        for n in p["names"]:
            key, rig_name = _morph_key(n, renames)
            if key not in keys:
                keys[key] = len(names)
                names.append(rig_name)
            slot.append(keys[key])
        slots.append(slot)
    V, M = surf["n_vertices"], len(names)
    positions = np.zeros((M, V, 3), np.float32)
    normals = np.zeros((M, V, 3), np.float32)
    for p, slot in zip(surf["parts"], slots):
        rows = slice(p["offset"], p["offset"] + p["pos"].shape[0])
        for k, m in enumerate(slot):  # per morph of a mesh (tens): a block copy each
            positions[m, rows] += p["mpos"][k]
            normals[m, rows] += p["mnrm"][k]
    return names, positions, normals


# ---- textures -------------------------------------------------------------------------
ATLAS_MAX = 2048  # atlas side (px): 2048^2 keeps the wrinkle and zone maps at ~90 MB
_ATLAS_PAD = 2  # texels between a tile's UV square and its edge (filtering stays inside)
ALPHA_MODES = {"OPAQUE": 0, "MASK": 1, "BLEND": 2}


def _srgb_encode(linear: np.ndarray) -> np.ndarray:
    return np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def _srgb_decode(srgb: np.ndarray) -> np.ndarray:
    return np.where(srgb <= 0.04045, srgb / 12.92, np.power((srgb + 0.055) / 1.055, 2.4))


class _TextureReader:
    """A material's textures, each image decoded once; an image that cannot be read (a
    codec we lack, a missing file) is None, with one warning naming it."""

    def __init__(self, r: GlbReader):
        self.r = r
        self._images: dict = {}

    def _source(self, info: dict) -> object:
        return next(iter(self.r.texture_sources(info)), None)

    def get(self, info: dict | None, material: dict, role: str) -> np.ndarray | None:
        """The image behind textureInfo ``info`` of ``material`` (``role``: what is drawn
        without it), or None."""
        if not info:
            return None
        source = self._source(info)
        if source not in self._images:
            try:
                self._images[source] = self.r.texture_image(info)
            except CaptureError as exc:
                self._images[source] = None
                image = self.r.gltf.get("images", [])[source] if isinstance(source, int) else {}
                label = image.get("name") or image.get("uri") or image.get("mimeType") or "unnamed"
                log.warning("%s (image '%s'); material '%s' is drawn %s", exc, str(label)[:80],
                            material.get("name", "unnamed"), role)
        return self._images[source]

    def base_colour(self, mat: dict) -> np.ndarray | None:
        return self.get(mat.get("pbrMetallicRoughness", {}).get("baseColorTexture"), mat,
                        "with its base colour factor instead")

    def normal(self, mat: dict) -> np.ndarray | None:
        return self.get(mat.get("normalTexture"), mat, "without its normal map")


def _alpha_mode(mat: dict) -> int:
    """0 OPAQUE, 1 MASK, 2 BLEND (glTF's ``alphaMode``; unknown words are opaque)."""
    return ALPHA_MODES.get(str(mat.get("alphaMode", "OPAQUE")).upper(), 0)


def _material_albedo(tr: _TextureReader, mat: dict, size: tuple[int, int] | None,
                     keep_alpha: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 sRGB base colour of a material (its texture times its factor, or
    the factor alone: ``size``, default 256²) and (H, W) uint8 its alpha (the texture's
    alpha times the factor's; 255 for an OPAQUE material, which glTF draws without it,
    unless ``keep_alpha``)."""
    pbr = mat.get("pbrMetallicRoughness", {})
    factor4 = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), np.float64)
    factor = factor4[:3]
    opaque = _alpha_mode(mat) == 0 and not keep_alpha
    image = tr.base_colour(mat)
    if image is None:
        if "baseColorFactor" not in pbr:
            factor = np.array([0.8, 0.55, 0.45])  # a mid skin tone where nothing is said
        colour = (np.clip(_srgb_encode(np.clip(factor, 0, 1)), 0, 1) * 255 + 0.5).astype(np.uint8)
        shape = size or (DEFAULT_TEXTURE_SIZE, DEFAULT_TEXTURE_SIZE)
        alpha = 255 if opaque or len(factor4) < 4 else int(np.clip(factor4[3], 0, 1) * 255 + 0.5)
        return np.broadcast_to(colour, shape + (3,)).copy(), np.full(shape, alpha, np.uint8)
    shape = image.shape[:2] if size is None else size
    alpha = np.full(shape, 255, np.uint8)
    if not opaque:
        if image.shape[2] == 4:
            alpha = _fit(image[:, :, 3:], shape, 1)[:, :, 0]
        if len(factor4) >= 4 and factor4[3] != 1.0:
            alpha = (alpha * np.clip(factor4[3], 0, 1) + 0.5).astype(np.uint8)
    image = _fit(image, shape)
    if np.allclose(factor, 1.0):
        return image, alpha
    lin = _srgb_decode(image.astype(np.float64) / 255.0) * factor
    return (np.clip(_srgb_encode(np.clip(lin, 0, 1)), 0, 1) * 255 + 0.5).astype(np.uint8), alpha


def _needs_atlas(r: GlbReader, used: list[int], largest: int | None) -> bool:
    """The drawn materials need a texture of their own each: two or more base-colour
    textures, or a MASK / BLEND material whose alpha the largest material's texture
    does not hold (another texture, none, or another alpha factor)."""
    materials = r.gltf.get("materials", [])

    def key(i):
        pbr = materials[i].get("pbrMetallicRoughness", {})
        # The image it samples (a WebP / KTX2 one named by an extension counts: a file
        # from gltfpack -tw or glTF-Transform webp has no plain source).
        source = next(iter(r.texture_sources(pbr.get("baseColorTexture"))), None)
        return source, (list(pbr.get("baseColorFactor", [1.0] * 4)) + [1.0])[3]

    sources = {key(i)[0] for i in used if key(i)[0] is not None}
    if len(sources) >= 2:
        return True
    clear = [i for i in used if _alpha_mode(materials[i])]
    return len(used) >= 2 and any(largest is None or key(i) != key(largest) for i in clear)


def _alpha_modes(g: dict, surf: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """(V,) uint8 alpha mode and (V,) float32 MASK cutoff of each vertex (its material's);
    None when every drawn material is opaque."""
    materials = g.get("materials", [])
    used = [int(i) for i in np.unique(surf["gltf_material"]) if i >= 0]
    if not any(_alpha_mode(materials[i]) for i in used):
        return None
    mode = np.zeros(surf["n_vertices"], np.uint8)
    cutoff = np.full(surf["n_vertices"], 0.5, np.float32)
    for i in used:
        sel = surf["gltf_material"] == i
        mode[sel] = _alpha_mode(materials[i])
        cutoff[sel] = float(materials[i].get("alphaCutoff", 0.5))
    return mode, cutoff


def _textures(r: GlbReader, surf: dict, mapping: dict, mapping_dir: Path, ours: dict | None) -> dict:
    """Albedo, its alpha (None where every material is opaque) and normal map (one
    texture set: the drawn materials packed into an atlas when they need textures of
    their own, UVs moved into each material's tile), wrinkle maps and zone masks at the
    albedo's size."""
    g = r.gltf
    materials = g.get("materials", [])
    tr = _TextureReader(r)
    uvs = surf["uv"].astype(np.float32)
    used = sorted(int(i) for i in np.unique(surf["gltf_material"]) if i >= 0)
    if _needs_atlas(r, used, surf["largest_material"]):
        albedo, alpha, normal_map, uvs = _atlas(tr, surf, used, materials)
    else:
        index = surf["largest_material"]
        mat = materials[index] if index is not None else {}
        # One texture for every material: its alpha is also the MASK / BLEND ones'.
        albedo, alpha = _material_albedo(tr, mat, None, keep_alpha=True)
        size = albedo.shape[:2]
        normal_map = tr.normal(mat)
        normal_map = _flat_normals(size) if normal_map is None else _fit(normal_map, size)
    modes = _alpha_modes(g, surf)
    size = albedo.shape[:2]
    out = {"albedo": albedo, "alpha": None if modes is None else alpha, "alpha_modes": modes,
           "normal_map": normal_map, "uvs": uvs}
    out.update(_detail_maps(r, size, mapping, mapping_dir, ours))
    return out


def _detail_maps(r: GlbReader, size: tuple[int, int], mapping: dict, mapping_dir: Path, ours: dict | None) -> dict:
    """Wrinkle maps (the file's own or the mapping's, flat "stretch" / "compress" where
    missing) and zone masks, at the albedo's ``size``."""
    if ours:
        wrinkle_names = [w["name"] for w in ours["wrinkle_maps"]]
        wrinkle_maps = [_fit(r.image(w["image"]), size) for w in ours["wrinkle_maps"]]
        zone_masks = np.concatenate([_fit(r.image(i), size, 4) for i in ours["zone_mask_images"]], 2)
    else:
        wrinkle_names, wrinkle_maps = [], []
        for name, file in mapping.get("wrinkle_maps", {}).items():
            wrinkle_names.append(str(name))
            wrinkle_maps.append(_fit(_read_image_file(mapping_dir / file), size))
        for name in ("stretch", "compress"):
            if name not in wrinkle_names:
                wrinkle_names.append(name)
                wrinkle_maps.append(_flat_normals(size))
        files = mapping.get("zone_masks")
        if files:
            if len(files) != 2:
                raise CaptureError("mapping: 'zone_masks' must list two RGBA images")
            zone_masks = np.concatenate([_fit(_read_image_file(mapping_dir / f), size, 4) for f in files], 2)
        else:
            zone_masks = np.zeros(size + (8,), np.uint8)
    return {"wrinkle_names": wrinkle_names, "wrinkle_maps": wrinkle_maps, "zone_masks": zone_masks}


def _flat_normals(size: tuple[int, int]) -> np.ndarray:
    flat = np.empty(tuple(size) + (3,), np.uint8)
    flat[:] = (128, 128, 255)
    return flat


def _atlas(tr: _TextureReader, surf: dict, used: list[int], materials: list
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every drawn material's base colour, alpha and normal map in one square grid of
    tiles, and the UVs moved into their material's tile (clamped to the tile: tiling UVs
    outside [0, 1] are not repeated).

    Returns:
        albedo (A, A, 3), alpha (A, A), normal map (A, A, 3), uvs (V, 2) float32.
    """
    slots = used + ([-1] if (surf["gltf_material"] < 0).any() else [])
    cols = int(np.ceil(np.sqrt(len(slots))))
    rows = -(-len(slots) // cols)
    largest = 0
    for i in used:
        img = tr.base_colour(materials[i])
        if img is not None:
            largest = max(largest, *img.shape[:2])
    tile = int(min(max(largest, 64), ATLAS_MAX // cols))
    albedo = np.zeros((rows * tile, cols * tile, 3), np.uint8)
    alpha = np.full((rows * tile, cols * tile), 255, np.uint8)
    normal = np.empty((rows * tile, cols * tile, 3), np.uint8)
    normal[:] = (128, 128, 255)
    uvs = np.clip(surf["uv"], 0.0, 1.0)
    out = np.zeros_like(uvs)
    inner = (tile - 2 * _ATLAS_PAD) / tile
    for s, i in enumerate(slots):
        row, col = divmod(s, cols)
        mat = materials[i] if i >= 0 else {}
        cell = np.s_[row * tile:(row + 1) * tile, col * tile:(col + 1) * tile]
        albedo[cell], alpha[cell] = _material_albedo(tr, mat, (tile, tile))
        nmap = tr.normal(mat)
        if nmap is not None:
            normal[cell] = _fit(nmap, (tile, tile))
        sel = surf["gltf_material"] == i
        out[sel, 0] = (col + _ATLAS_PAD / tile + uvs[sel, 0] * inner) / cols
        out[sel, 1] = (row + _ATLAS_PAD / tile + uvs[sel, 1] * inner) / rows
    return albedo, alpha, normal, out.astype(np.float32)


def _weld(vertices: np.ndarray) -> np.ndarray:
    """Vertices at the same position (to 1e-5 cm) share an id."""
    key = np.round(vertices.astype(np.float64) * 1e5).astype(np.int64)
    _, ids = np.unique(key, axis=0, return_inverse=True)
    return ids.reshape(-1)


def _apply_ours(rig: FaceRig, ours: dict, m: dict) -> FaceRig:
    """A capture2face export: restore what glTF has no slot for, exactly."""
    if list(ours["bone_names"]) != rig.bone_names:
        raise CaptureError("the .glb's capture2face extras do not match its skin's joints")
    regions = np.zeros((len(ours["region_names"]), rig.n_vertices), np.float32)
    if m["regions"] is not None:
        regions = np.ascontiguousarray(m["regions"][:, : len(regions)].T).astype(np.float32)
    P = len(ours["pose_names"])
    eyes = {}
    if ours.get("eye_joints") and m["joints"] is not None:
        # Eyeball vertices: skinned to an eye joint (indices after the bones), back to the head.
        raw = np.asarray(m["joints"], np.int64)
        heavy = np.take_along_axis(raw, np.argmax(m["weights"], axis=1)[:, None], 1)[:, 0]
        side = np.where(heavy >= rig.n_bones, heavy - rig.n_bones, -1).astype(np.int8)
        joints, weights = rig.skin_joints.copy(), rig.skin_weights.copy()
        joints[side >= 0], weights[side >= 0] = 0, [1.0, 0.0, 0.0, 0.0]
        eyes = dict(eye_centres=np.asarray(ours["eye_centres_cm"], np.float32).reshape(2, 3),
                    eye_vertex_side=side, skin_joints=joints, skin_weights=weights)
    if "landmark_faces" in ours and "landmark_bary" in ours:  # landmarks on the surface
        eyes.update(landmark_faces=np.asarray(ours["landmark_faces"], np.int32).reshape(-1, 3),
                    landmark_bary=np.asarray(ours["landmark_bary"], np.float32).reshape(-1, 3))
    return rig.replace(
        **eyes,
        bone_rest=np.asarray(ours["bone_rest_cm"], np.float32).reshape(-1, 3),
        bone_parents=np.asarray(ours["bone_parents"], np.int32),
        bone_landmarks=np.asarray(ours["bone_landmarks"], np.int32),
        bone_groups=np.asarray(ours["bone_groups"], np.int32),
        landmark_vertices=np.asarray(ours["landmark_vertices"], np.int32),
        pose_names=list(ours["pose_names"]),
        pose_bones=np.asarray(ours["pose_bones_cm"], np.float32).reshape(P, rig.n_bones, 3),
        pose_morph_weights=np.asarray(ours["pose_morph_weights"], np.float32).reshape(P, rig.n_morphs),
        pose_maps=np.asarray(ours["pose_maps"], np.int32),
        zone_names=list(ours["zone_names"]),
        zone_table=np.asarray(ours["zone_table"], np.float32).reshape(rig.n_morphs, -1),
        region_names=list(ours["region_names"]), region_weights=regions,
    )


def _apply_mapping(rig: FaceRig, mapping: dict) -> FaceRig:
    """Bones -> landmarks, groups, poses, zone table from the mapping JSON, then defaults
    lent by the default avatar for what it leaves out."""
    names = rig.bone_names
    alias = {n: i for i, n in enumerate(names)}
    head_bone = mapping.get("head_bone")
    if head_bone:
        alias[head_bone] = 0

    def bone(name: str) -> int:
        if name not in alias:
            raise CaptureError(f"mapping: '{name}' is not a bone of the character")
        return alias[name]

    landmarks = rig.bone_landmarks.copy()
    for name, lm in mapping.get("bones", {}).items():
        if not 0 <= int(lm) < N_LANDMARKS:
            raise CaptureError(f"mapping: landmark {lm} of bone '{name}' is outside 0..{N_LANDMARKS - 1}")
        landmarks[bone(name)] = int(lm)
    groups = np.arange(rig.n_bones, dtype=np.int32)
    for gid, members in enumerate(mapping.get("bone_groups", [])):
        for name in members:
            groups[bone(name)] = rig.n_bones + gid
    _, groups = np.unique(groups, return_inverse=True)
    lmv = rig.landmark_vertices.copy()
    for lm, v in mapping.get("landmark_vertices", {}).items():
        if not (0 <= int(lm) < N_LANDMARKS and 0 <= int(v) < rig.n_vertices):
            raise CaptureError(f"mapping: landmark_vertices entry {lm}: {v} is out of range")
        lmv[int(lm)] = int(v)
    rig = rig.replace(bone_landmarks=landmarks.astype(np.int32), bone_groups=groups.astype(np.int32),
                      landmark_vertices=lmv)

    poses = mapping.get("poses", {})
    pose_names = list(dict.fromkeys(["stretch", "compress", *poses]))
    pose_bones = np.repeat(rig.bone_rest[None], len(pose_names), 0).astype(np.float32)
    pose_morph = np.zeros((len(pose_names), rig.n_morphs), np.float32)
    pose_maps = np.zeros(len(pose_names), np.int32)
    for p, pname in enumerate(pose_names):
        spec = poses.get(pname, {})
        for name, off in spec.get("offsets", {}).items():
            pose_bones[p, bone(name)] = rig.bone_rest[bone(name)] + np.asarray(off, np.float32)
        for name, xyz in spec.get("positions", {}).items():
            pose_bones[p, bone(name)] = np.asarray(xyz, np.float32)
        for mname, wv in spec.get("morphs", {}).items():
            if mname in rig.morph_names:
                pose_morph[p, rig.morph_index(mname)] = float(wv)
        wmap = spec.get("wrinkle_map", pname)
        if wmap in rig.wrinkle_map_names:
            pose_maps[p] = rig.wrinkle_map_names.index(wmap)
        elif "wrinkle_map" in spec:
            raise CaptureError(f"mapping: pose '{pname}' names wrinkle map '{wmap}', which is not in 'wrinkle_maps'")
    table = rig.zone_table.copy()
    given_table = {str(k).lower(): v for k, v in mapping.get("zone_table", {}).items()}
    for i, mname in enumerate(rig.morph_names):
        if mname.lower() in given_table:
            row = np.asarray(given_table[mname.lower()], np.float32)
            if row.shape != (len(ZONE_NAMES),):
                raise CaptureError(f"mapping: zone_table['{mname}'] must have {len(ZONE_NAMES)} values")
            table[i] = row
    rig = rig.replace(pose_names=pose_names, pose_bones=pose_bones, pose_morph_weights=pose_morph,
                      pose_maps=pose_maps, zone_table=table)
    return _lend_from_avatar(rig, posed={p for p in poses if poses[p].get("offsets") or poses[p].get("positions")},
                             tabled={k for k in given_table})


def _lend_from_avatar(rig: FaceRig, posed: set, tabled: set) -> FaceRig:
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
    lm_pos = {}
    for b in range(1, avatar.n_bones):
        if avatar.bone_landmarks[b] >= 0:
            lm_pos[int(avatar.bone_landmarks[b])] = b
    canon = avatar.vertices[avatar.landmark_vertices.clip(0)].astype(np.float64)  # (L, 3)
    canon[avatar.landmark_vertices < 0] = np.nan
    ok = [b for b in known if np.isfinite(canon[rig.bone_landmarks[b]]).all()]
    if len(ok) < 3:
        return rig
    s, rot, t = similarity(canon[rig.bone_landmarks[ok]], rig.bone_rest[ok].astype(np.float64))
    fitted = canon @ (s * rot).T + t  # avatar landmarks on the character

    # Poses: the avatar's offsets of the bone on the same landmark, rotated and scaled.
    pose_bones = rig.pose_bones.copy()
    for p, pname in enumerate(rig.pose_names):
        if pname in posed or pname not in avatar.pose_names:
            continue
        ap = avatar.pose_index(pname)
        for b in known:
            ab = lm_pos.get(int(rig.bone_landmarks[b]))
            if ab is not None:
                off = avatar.pose_bones[ap, ab] - avatar.bone_rest[ab]
                pose_bones[p, b] = rig.bone_rest[b] + (s * rot @ off).astype(np.float32)
    # Zone table rows by (case-insensitive) morph name.
    amorph = {n.lower(): i for i, n in enumerate(avatar.morph_names)}
    table = rig.zone_table.copy()
    for i, n in enumerate(rig.morph_names):
        if n.lower() not in tabled and n.lower() in amorph:
            table[i] = avatar.zone_table[amorph[n.lower()]]
    # Regions and landmark vertices: nearest fitted avatar landmark / nearest skin vertex.

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
    return rig.replace(pose_bones=pose_bones, zone_table=table, region_weights=regions.astype(np.float32),
                       landmark_vertices=lmv.astype(np.int32))

"""Meshes and their morph targets: one glTF mesh's triangle primitives read into one
vertex array (in the mesh's own space): primitives that share their POSITION accessor
share vertices, every other primitive appends its own."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import GlbReader, texture_transform
from capture2face.gltf.mapping import Mapping
from capture2face.gltf.materials import material_code

TRIANGLE_MODES = (4, 5, 6)  # triangles, strip, fan


@dataclass(frozen=True)
class MeshArrays:
    """One mesh's vertex arrays (n vertices, K morph targets); None where no primitive
    has the attribute.

    positions (n, 3), normals (n, 3) (NaN where a primitive has none), uvs (n, 2) as the
    base colour textures sample them, tangents (n, 4), joints / weights (n, J) (the JOINTS_s
    / WEIGHTS_s sets side by side), triangles (T, 3), material (n,) uint8 codes,
    gltf_material (n,) the glTF material (-1: none), position_ids (n,) and regions (n, R)
    (our own export's ``_POSITION_ID`` / ``_REGIONS_c``), morph_positions / morph_normals
    (K, n, 3) (NaN normals where a target has none), target_names (K,), the material of
    the primitive with the most triangles and the mesh's triangle count.
    """

    positions: np.ndarray
    normals: np.ndarray | None
    uvs: np.ndarray | None
    tangents: np.ndarray | None
    joints: np.ndarray | None
    weights: np.ndarray | None
    triangles: np.ndarray
    material: np.ndarray
    gltf_material: np.ndarray
    position_ids: np.ndarray | None
    regions: np.ndarray | None
    morph_positions: np.ndarray
    morph_normals: np.ndarray
    target_names: list[str] = field(default_factory=list)
    largest_material: int | None = None
    tri_count: int = 0


@dataclass
class _Block:
    """The primitives of one POSITION accessor, gathered: the first primitive, the vertex
    count, triangles per primitive, per-vertex material codes and glTF materials, and
    (primitive, the vertices it draws) for its UVs."""

    prim: dict
    n: int
    material: np.ndarray
    gltf_material: np.ndarray
    tris: list[np.ndarray] = field(default_factory=list)
    tri_count: int = 0
    uv_parts: list[tuple[dict, np.ndarray]] = field(default_factory=list)


def triangles(r: GlbReader, prim: dict, n_vertices: int) -> np.ndarray:
    """(T, 3) int64 triangles of a primitive (strips and fans unrolled; none for points and lines)."""
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


def _counted(r: GlbReader, values: np.ndarray, n: int, what: str) -> np.ndarray:
    """``values`` when it has one row per vertex; a malformed file otherwise."""
    if len(values) != n:
        raise CaptureError(f"{r.path}: {what} has {len(values)} values for {n} vertices")
    return values


def target_names(mesh: dict, n_targets: int) -> list[str]:
    """The mesh's morph target names (``extras.targetNames``), ``target_<k>`` where unnamed."""
    names = mesh.get("extras", {}).get("targetNames") or \
        next((p.get("extras", {}).get("targetNames") for p in mesh.get("primitives", [])
              if p.get("extras", {}).get("targetNames")), None)
    out = [str(n) for n in names][:n_targets] if names else []
    return out + [f"target_{i}" for i in range(len(out), n_targets)]


def _primitive_blocks(r: GlbReader, mesh: dict, mapping: Mapping) -> tuple[dict[int, _Block], list[int], int | None]:
    """The mesh's triangle primitives grouped by their POSITION accessor. Returns the
    blocks, their accessors in first-seen order, and the number of morph targets (the
    same on every primitive)."""
    blocks: dict[int, _Block] = {}
    order: list[int] = []
    n_targets = None
    for prim in mesh.get("primitives", []):
        attrs = prim.get("attributes", {})
        if "POSITION" not in attrs or prim.get("mode", 4) not in TRIANGLE_MODES:
            continue
        key = attrs["POSITION"]
        pos = r.accessor(key).astype(np.float64)
        if key not in blocks:
            order.append(key)
            blocks[key] = _Block(prim=prim, n=len(pos), material=np.zeros(len(pos), np.uint8),
                                 gltf_material=np.full(len(pos), -1, np.int64))
        blk = blocks[key]
        tris = triangles(r, prim, len(pos))
        blk.tris.append(tris)
        code = material_code(r.gltf, prim, mapping, mesh.get("name", ""))
        used = np.unique(tris)
        blk.uv_parts.append((prim, used))
        if code:
            blk.material[used] = code
        blk.gltf_material[used] = prim.get("material", -1)
        blk.tri_count += len(tris)
        nt = len(prim.get("targets", []))
        if n_targets is not None and nt != n_targets:
            raise CaptureError(f"{r.path}: the mesh's primitives have different numbers of morph targets")
        n_targets = nt
    if not order:
        raise CaptureError(f"{r.path}: the mesh has no triangle primitives")
    return blocks, order, n_targets


def attribute(r: GlbReader, prim: dict, name: str, as_float: bool = True) -> np.ndarray | None:
    """A vertex attribute of ``prim`` (one row per vertex), or None when it has none."""
    if name in prim.get("attributes", {}):
        return _counted(r, r.accessor(prim["attributes"][name], as_float=as_float), len(
            r.accessor(prim["attributes"]["POSITION"])), name)
    return None


def _texture_uvs(r: GlbReader, blk: _Block) -> np.ndarray | None:
    """(n, 2) UVs of a block as its base colour textures sample them: per primitive, the
    texture's coordinate set with its ``KHR_texture_transform`` applied (gltfpack's
    quantized UVs rely on it) at the vertices the primitive draws; TEXCOORD_0 as stored
    where a primitive has no base colour texture."""
    uv = attribute(r, blk.prim, "TEXCOORD_0")
    materials = r.gltf.get("materials", [])
    for prim, used in blk.uv_parts:
        mat = materials[prim["material"]] if "material" in prim else {}
        info = (mat.get("pbrMetallicRoughness") or {}).get("baseColorTexture")
        if not info:
            continue
        tex_coord, m = texture_transform(info)
        src = attribute(r, prim, f"TEXCOORD_{tex_coord}")
        if src is None:
            continue
        uv = np.array(src, np.float64) if uv is None else np.array(uv, np.float64)
        uv[used] = src[used].astype(np.float64) @ m[:, :2].T + m[:, 2]
    return uv


def _morph_targets(r: GlbReader, prim: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(K, n, 3) position and normal deltas of a primitive's targets (zero positions, NaN
    normals where a target has none)."""
    targets = prim.get("targets", [])
    if not targets:
        return np.zeros((0, n, 3)), np.zeros((0, n, 3))
    mpos = np.stack([_counted(r, r.accessor(t["POSITION"]), n, "a morph target").astype(np.float64)
                     if "POSITION" in t else np.zeros((n, 3)) for t in targets])
    mnrm = np.stack([_counted(r, r.accessor(t["NORMAL"]), n, "a morph target").astype(np.float64)
                     if "NORMAL" in t else np.full((n, 3), np.nan) for t in targets])
    return mpos, mnrm


def _block_arrays(r: GlbReader, key: int, blk: _Block, offset: int) -> MeshArrays:
    """One block's vertex arrays (None where its primitive lacks the attribute), its
    triangles shifted by ``offset``, and its morph target deltas."""
    prim = blk.prim
    # Read in this order: a malformed file is refused for its first wrong attribute.
    positions = r.accessor(key).astype(np.float64)
    normals = attribute(r, prim, "NORMAL")
    uvs = _texture_uvs(r, blk)
    tangents = attribute(r, prim, "TANGENT")
    j = [attribute(r, prim, f"JOINTS_{s}", as_float=False) for s in range(2)]
    w = [attribute(r, prim, f"WEIGHTS_{s}") for s in range(2)]
    pairs = [(jj, ww) for jj, ww in zip(j, w) if jj is not None and ww is not None]
    tris = np.concatenate(blk.tris) + offset
    mat = attribute(r, prim, "_MATERIAL")
    pid = attribute(r, prim, "_POSITION_ID")
    chunks = []
    c = 0
    while f"_REGIONS_{c}" in prim.get("attributes", {}):
        chunks.append(attribute(r, prim, f"_REGIONS_{c}"))
        c += 1
    mpos, mnrm = _morph_targets(r, prim, blk.n)
    return MeshArrays(
        positions=positions, normals=normals, uvs=uvs, tangents=tangents,
        joints=np.concatenate([p[0] for p in pairs], 1).astype(np.int64) if pairs else None,
        weights=np.concatenate([p[1] for p in pairs], 1).astype(np.float32) if pairs else None,
        triangles=tris,
        material=np.rint(mat[:, 0]).astype(np.uint8) if mat is not None else blk.material,
        gltf_material=blk.gltf_material,
        position_ids=None if pid is None else np.rint(pid[:, 0]).astype(np.int64),
        regions=np.concatenate(chunks, 1) if chunks else None,
        morph_positions=mpos, morph_normals=mnrm,
    )


def _padded(parts: list[np.ndarray | None], sizes: list[int], dtype) -> np.ndarray | None:
    """Skin joints or weights of the blocks side by side at the widest block's width
    (zeros where a block has fewer or none); None where no block has any."""
    widths = [p.shape[1] for p in parts if p is not None]
    width = max(widths) if widths else 0
    if not width:
        return None
    return np.concatenate([np.pad(p, ((0, 0), (0, width - p.shape[1]))) if p is not None
                           else np.zeros((n, width), dtype) for p, n in zip(parts, sizes)])


def _merge_blocks(parts: list[MeshArrays], blocks: list[_Block], mesh: dict, n_targets: int | None) -> MeshArrays:
    """The blocks' arrays concatenated into one vertex array; an attribute some blocks
    lack is filled (NaN normals and tangents, zero UVs, joints and weights), one that
    none has is None."""
    sizes = [b.n for b in blocks]

    def cat(name, width, fill):
        values = [getattr(p, name) for p in parts]
        if all(v is None for v in values):
            return None
        return np.concatenate([v if v is not None else np.full((n, width), fill) for v, n in zip(values, sizes)])

    def every(name):
        values = [getattr(p, name) for p in parts]
        return None if any(v is None for v in values) else np.concatenate(values)

    return MeshArrays(
        positions=np.concatenate([p.positions for p in parts]),
        triangles=np.concatenate([p.triangles for p in parts]).astype(np.int64),
        material=np.concatenate([p.material for p in parts]),
        gltf_material=np.concatenate([p.gltf_material for p in parts]),
        morph_positions=np.concatenate([p.morph_positions for p in parts], axis=1),
        morph_normals=np.concatenate([p.morph_normals for p in parts], axis=1),
        normals=cat("normals", 3, np.nan), uvs=cat("uvs", 2, 0.0), tangents=cat("tangents", 4, np.nan),
        joints=_padded([p.joints for p in parts], sizes, np.int64),
        weights=_padded([p.weights for p in parts], sizes, np.float32),
        position_ids=every("position_ids"), regions=every("regions"),
        largest_material=max(blocks, key=lambda b: b.tri_count).prim.get("material"),
        tri_count=sum(b.tri_count for b in blocks),
        target_names=target_names(mesh, n_targets or 0),
    )


def read_mesh(r: GlbReader, mesh: dict, mapping: Mapping) -> MeshArrays:
    """One mesh's primitives merged into one vertex array, in the mesh's own space."""
    blocks, order, n_targets = _primitive_blocks(r, mesh, mapping)
    parts = []
    offset = 0
    for key in order:
        parts.append(_block_arrays(r, key, blocks[key], offset))
        offset += blocks[key].n
    return _merge_blocks(parts, [blocks[k] for k in order], mesh, n_targets)

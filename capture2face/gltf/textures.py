"""Textures: the albedo (baseColorTexture times baseColorFactor), its alpha and the normal
map of the drawn materials (one texture set, or an atlas of one tile per material when
they need textures of their own), then the wrinkle maps and zone masks at its size."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from capture2face.errors import CaptureError
from capture2face.gltf.container import GlbReader, decode_image
from capture2face.gltf.mapping import Mapping
from capture2face.gltf.materials import alpha_mode, alpha_modes, used_materials
from capture2face.runtime.log import log

DEFAULT_TEXTURE_SIZE = 256
ATLAS_MAX = 2048  # atlas side (px): 2048^2 keeps the wrinkle and zone maps at ~90 MB
_ATLAS_PAD = 2  # texels between a tile's UV square and its edge (filtering stays inside)


@dataclass(frozen=True)
class Textures:
    """albedo (H, W, 3) uint8 sRGB, alpha (H, W) uint8 or None (every material opaque),
    alpha_mode / alpha_cutoff (V,) or None, normal_map (H, W, 3), uvs (V, 2) float32 (moved
    into their tile where there is an atlas), wrinkle_names (N,), wrinkle_maps (N, H, W, 3),
    zone_masks (H, W, 8)."""

    albedo: np.ndarray
    alpha: np.ndarray | None
    alpha_mode: np.ndarray | None
    alpha_cutoff: np.ndarray | None
    normal_map: np.ndarray
    uvs: np.ndarray
    wrinkle_names: list[str]
    wrinkle_maps: np.ndarray
    zone_masks: np.ndarray


def read_image_file(path: Path) -> np.ndarray:
    """(H, W, C) uint8 image of a file the mapping names."""
    try:
        return decode_image(path.read_bytes())
    except (OSError, ValueError):
        raise CaptureError(f"{path}: image not found or unreadable") from None


def fit_image(image: np.ndarray, size: tuple[int, int], channels: int = 3) -> np.ndarray:
    """Resize (H, W) and keep ``channels`` channels (alpha dropped, grey expanded)."""
    if image.shape[2] < channels:
        image = np.concatenate([image, np.zeros(image.shape[:2] + (channels - image.shape[2],), np.uint8)], 2)
    image = np.ascontiguousarray(image[:, :, :channels])
    if image.shape[:2] != size:
        image = cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_AREA)
        if image.ndim == 2:
            image = image[:, :, None]
    return image


def flat_normals(size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) a flat tangent-space normal map."""
    flat = np.empty(tuple(size) + (3,), np.uint8)
    flat[:] = (128, 128, 255)
    return flat


def _srgb_encode(linear: np.ndarray) -> np.ndarray:
    return np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.power(linear, 1 / 2.4) - 0.055)


def _srgb_decode(srgb: np.ndarray) -> np.ndarray:
    return np.where(srgb <= 0.04045, srgb / 12.92, np.power((srgb + 0.055) / 1.055, 2.4))


class TextureReader:
    """A material's textures, each image decoded once; an image that cannot be read (a
    codec we lack, a missing file) is None, with one warning naming it."""

    def __init__(self, r: GlbReader):
        self.r = r
        self._images: dict = {}

    def get(self, info: dict | None, material: dict, role: str) -> np.ndarray | None:
        """The image behind textureInfo ``info`` of ``material`` (``role``: what is drawn
        without it), or None."""
        if not info:
            return None
        source = next(iter(self.r.texture_sources(info)), None)
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


def material_albedo(tr: TextureReader, mat: dict, size: tuple[int, int] | None,
                    keep_alpha: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 sRGB base colour of a material (its texture times its factor, or
    the factor alone: ``size``, default 256²) and (H, W) uint8 its alpha (the texture's
    alpha times the factor's; 255 for an OPAQUE material, which glTF draws without it,
    unless ``keep_alpha``)."""
    pbr = mat.get("pbrMetallicRoughness", {})
    factor4 = np.asarray(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0]), np.float64)
    factor = factor4[:3]
    opaque = alpha_mode(mat) == 0 and not keep_alpha
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
            alpha = fit_image(image[:, :, 3:], shape, 1)[:, :, 0]
        if len(factor4) >= 4 and factor4[3] != 1.0:
            alpha = (alpha * np.clip(factor4[3], 0, 1) + 0.5).astype(np.uint8)
    image = fit_image(image, shape)
    if np.allclose(factor, 1.0):
        return image, alpha
    lin = _srgb_decode(image.astype(np.float64) / 255.0) * factor
    return (np.clip(_srgb_encode(np.clip(lin, 0, 1)), 0, 1) * 255 + 0.5).astype(np.uint8), alpha


def needs_atlas(r: GlbReader, used: list[int], largest: int | None) -> bool:
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
    clear = [i for i in used if alpha_mode(materials[i])]
    return len(used) >= 2 and any(largest is None or key(i) != key(largest) for i in clear)


def atlas(tr: TextureReader, uvs: np.ndarray, gltf_material: np.ndarray, used: list[int], materials: list
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every drawn material's base colour, alpha and normal map in one square grid of
    tiles, and the UVs (V, 2) moved into their material's tile (``gltf_material`` (V,);
    clamped to the tile: tiling UVs outside [0, 1] are not repeated).

    Returns:
        albedo (A, A, 3), alpha (A, A), normal map (A, A, 3), uvs (V, 2) float32.
    """
    slots = used + ([-1] if (gltf_material < 0).any() else [])
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
    uvs = np.clip(uvs, 0.0, 1.0)
    out = np.zeros_like(uvs)
    inner = (tile - 2 * _ATLAS_PAD) / tile
    for s, i in enumerate(slots):
        row, col = divmod(s, cols)
        mat = materials[i] if i >= 0 else {}
        cell = np.s_[row * tile:(row + 1) * tile, col * tile:(col + 1) * tile]
        albedo[cell], alpha[cell] = material_albedo(tr, mat, (tile, tile))
        nmap = tr.normal(mat)
        if nmap is not None:
            normal[cell] = fit_image(nmap, (tile, tile))
        sel = gltf_material == i
        out[sel, 0] = (col + _ATLAS_PAD / tile + uvs[sel, 0] * inner) / cols
        out[sel, 1] = (row + _ATLAS_PAD / tile + uvs[sel, 1] * inner) / rows
    return albedo, alpha, normal, out.astype(np.float32)


def _detail_maps(r: GlbReader, size: tuple[int, int], mapping: Mapping, ours: dict | None
                 ) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Wrinkle map names, wrinkle maps (N, H, W, 3) (the file's own or the mapping's, flat
    "stretch" / "compress" where missing) and zone masks (H, W, 8), at the albedo's ``size``."""
    if ours:
        wrinkle_names = [w["name"] for w in ours["wrinkle_maps"]]
        wrinkle_maps = [fit_image(r.image(w["image"]), size) for w in ours["wrinkle_maps"]]
        zone_masks = np.concatenate([fit_image(r.image(i), size, 4) for i in ours["zone_mask_images"]], 2)
        return wrinkle_names, np.stack(wrinkle_maps), zone_masks
    wrinkle_names, wrinkle_maps = [], []
    for name, file in mapping.wrinkle_maps.items():
        wrinkle_names.append(str(name))
        wrinkle_maps.append(fit_image(read_image_file(mapping.directory / file), size))
    for name in ("stretch", "compress"):
        if name not in wrinkle_names:
            wrinkle_names.append(name)
            wrinkle_maps.append(flat_normals(size))
    if mapping.zone_masks:  # two images (the mapping's check)
        zone_masks = np.concatenate([fit_image(read_image_file(mapping.directory / f), size, 4)
                                     for f in mapping.zone_masks], 2)
    else:
        zone_masks = np.zeros(size + (8,), np.uint8)
    return wrinkle_names, np.stack(wrinkle_maps), zone_masks


def read_textures(r: GlbReader, uvs: np.ndarray, gltf_material: np.ndarray, largest_material: int | None,
                  mapping: Mapping, ours: dict | None) -> Textures:
    """Albedo, its alpha (None where every material is opaque) and normal map (one
    texture set: the drawn materials packed into an atlas when they need textures of
    their own, UVs (V, 2) moved into each material's tile), wrinkle maps and zone masks at
    the albedo's size. ``gltf_material`` (V,): each vertex's glTF material."""
    materials = r.gltf.get("materials", [])
    tr = TextureReader(r)
    used = used_materials(gltf_material)
    if needs_atlas(r, used, largest_material):
        albedo, alpha, normal_map, uvs = atlas(tr, uvs, gltf_material, used, materials)
    else:
        uvs = uvs.astype(np.float32)
        mat = materials[largest_material] if largest_material is not None else {}
        # One texture for every material: its alpha is also the MASK / BLEND ones'.
        albedo, alpha = material_albedo(tr, mat, None, keep_alpha=True)
        size = albedo.shape[:2]
        normal_map = tr.normal(mat)
        normal_map = flat_normals(size) if normal_map is None else fit_image(normal_map, size)
    modes = alpha_modes(r.gltf, gltf_material)
    wrinkle_names, wrinkle_maps, zone_masks = _detail_maps(r, albedo.shape[:2], mapping, ours)
    return Textures(albedo=albedo, alpha=None if modes is None else alpha,
                    alpha_mode=None if modes is None else modes[0], alpha_cutoff=None if modes is None else modes[1],
                    normal_map=normal_map, uvs=uvs, wrinkle_names=wrinkle_names, wrinkle_maps=wrinkle_maps,
                    zone_masks=zone_masks)

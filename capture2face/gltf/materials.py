"""Materials: what each draws as (skin, eye, mouth, teeth, hair), alpha modes, double
sidedness and the see-through overlays landmarks must not land on."""

from __future__ import annotations

import numpy as np

from capture2face.gltf.mapping import Mapping

MATERIAL_CODES = {"skin": 0, "eye": 1, "mouth": 2, "teeth": 3, "hair": 4}
ALPHA_MODES = {"OPAQUE": 0, "MASK": 1, "BLEND": 2}
# Lashes, brows and hair cards: drawn as skin, not as an eye (no glossy highlight on
# lashes named "EyeLashes"), never the face's skin (no landmarks, no wrinkles).
_HAIR_WORDS = ("lash", "brow", "hair", "beard", "moustache", "mustache")
_EYE_WORDS = ("eye", "iris", "cornea", "sclera", "pupil")
_TEETH_WORDS = ("teeth", "tooth", "tongue")
_MOUTH_WORDS = ("mouth", "gum")
_OVERLAY_WORDS = ("lash", "brow", "hair", "glass", "lens", "beard", "fur")


def material_code(g: dict, prim: dict, mapping: Mapping, mesh_name: str = "") -> int:
    """0 skin, 1 eye, 2 mouth, 3 teeth, 4 hair: the mapping's word for the material, else
    its name's, else the mesh's name's (characters often share one material between face,
    eyes and teeth, in meshes named after them)."""
    name = str(g.get("materials", [])[prim["material"]].get("name", "")) if "material" in prim else ""
    if name in mapping.materials:  # a word the mapping's check allowed
        return MATERIAL_CODES[str(mapping.materials[name]).lower()]
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


def alpha_mode(mat: dict) -> int:
    """0 OPAQUE, 1 MASK, 2 BLEND (glTF's ``alphaMode``; unknown words are opaque)."""
    return ALPHA_MODES.get(str(mat.get("alphaMode", "OPAQUE")).upper(), 0)


def used_materials(gltf_material: np.ndarray) -> list[int]:
    """The glTF materials the vertices draw with (``gltf_material`` (V,), -1: none), sorted."""
    return sorted(int(i) for i in np.unique(gltf_material) if i >= 0)


def alpha_modes(g: dict, gltf_material: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(V,) uint8 alpha mode and (V,) float32 MASK cutoff of each vertex (its material's,
    ``gltf_material`` (V,)); None when every drawn material is opaque."""
    materials = g.get("materials", [])
    used = used_materials(gltf_material)
    if not any(alpha_mode(materials[i]) for i in used):
        return None
    mode = np.zeros(len(gltf_material), np.uint8)
    cutoff = np.full(len(gltf_material), 0.5, np.float32)
    for i in used:
        sel = gltf_material == i
        mode[sel] = alpha_mode(materials[i])
        cutoff[sel] = float(materials[i].get("alphaCutoff", 0.5))
    return mode, cutoff


def double_sided(g: dict, gltf_material: np.ndarray) -> bool:
    """Whether any drawn material is double-sided (the whole character is then drawn
    without culling: one draw call); a primitive without a material is single-sided."""
    materials = g.get("materials", [])
    return any(bool(materials[i].get("doubleSided", False)) for i in used_materials(gltf_material))


def overlay_vertices(g: dict, gltf_material: np.ndarray, largest_material: int | None,
                     mesh_spans: list[tuple[int, slice, int]]) -> np.ndarray | None:
    """(V,) bool: vertices of see-through overlays in front of the face that landmarks must
    not land on (alpha MASK / BLEND materials: lash and hair cards, glass; meshes or
    materials named lash, brow, hair, glass...), or None where there are none. The material
    and the mesh with the most triangles (the skin, whatever its name or alpha mode) never.
    ``mesh_spans``: per drawn mesh (node index, its rows, its triangle count)."""
    materials = g.get("materials", [])
    see_through = np.array([str(m.get("alphaMode", "OPAQUE")).upper() in ("MASK", "BLEND")
                            or any(w in str(m.get("name", "")).lower() for w in _OVERLAY_WORDS)
                            for m in materials] + [False], bool)  # index -1: no material
    if largest_material is not None:
        see_through[int(largest_material)] = False
    out = see_through[gltf_material]
    largest = max(range(len(mesh_spans)), key=lambda k: mesh_spans[k][2])
    for k, (ni, rows, _) in enumerate(mesh_spans):
        name = str(g["meshes"][g["nodes"][ni]["mesh"]].get("name", "")).lower()
        if k != largest and any(w in name for w in _OVERLAY_WORDS):
            out[rows] = True
    return out if out.any() else None

"""Morph targets merged by name: one FaceRig morph per name over every mesh that carries
it, ARKit names matched in any spelling (``eyeBlink_L`` on the head and ``eyeBlinkLeft``
on the eyes are one morph)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.gltf.surface import Surface
from capture2face.rig.arkit_names import canonical_arkit


@dataclass(frozen=True)
class Morphs:
    """M morphs over V vertices: names (M,), positions and normals (M, V, 3) float32 deltas."""

    names: list[str]
    positions: np.ndarray
    normals: np.ndarray


def morph_key(name: str, renames: dict[str, str]) -> tuple[str, str]:
    """(merge key, rig name) of a morph: the mapping's ARKit name (``renames``:
    :meth:`~capture2face.gltf.mapping.Mapping.arkit_renames`), else the ARKit name it spells
    (any case or side suffix) with the character's own spelling, else itself."""
    if name in renames:
        return renames[name], renames[name]
    arkit = canonical_arkit(name)
    return (arkit, name) if arkit is not None else (name, name)


def merge_morphs(surface: Surface, renames: dict[str, str]) -> Morphs:
    """One morph per name over all meshes: every mesh that carries a morph of that name
    (head, eyes, teeth) gets its deltas in the rig's morph of the name (ARKit names
    matched with their variants, :func:`~capture2face.rig.arkit_names.canonical_arkit`)."""
    keys: dict[str, int] = {}
    names: list[str] = []
    slots = []
    for p in surface.parts:
        slot = []
        for n in p.morph_names:
            key, rig_name = morph_key(n, renames)
            if key not in keys:
                keys[key] = len(names)
                names.append(rig_name)
            slot.append(keys[key])
        slots.append(slot)
    V, M = surface.n_vertices, len(names)
    positions = np.zeros((M, V, 3), np.float32)
    normals = np.zeros((M, V, 3), np.float32)
    for p, slot in zip(surface.parts, slots):
        for k, m in enumerate(slot):  # per morph of a mesh (tens): a block copy each
            positions[m, p.rows] += p.morph_positions[k]
            normals[m, p.rows] += p.morph_normals[k]
    return Morphs(names=names, positions=positions, normals=normals)

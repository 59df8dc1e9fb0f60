"""The scene graph: nodes' local and world matrices, and the nodes that draw a mesh."""

from __future__ import annotations

import numpy as np

from capture2face.errors import CaptureError
from capture2face.maths.rotations import quaternion_matrix


def local_matrix(node: dict) -> np.ndarray:
    """(4, 4) a node's transform in its parent's space (``matrix`` or TRS)."""
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    m[:3, :3] = quaternion_matrix(node.get("rotation", [0, 0, 0, 1])) * np.asarray(node.get("scale", [1, 1, 1]))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def parents(nodes: list[dict]) -> dict[int, int]:
    """Node index -> its parent's index (roots are absent)."""
    return {c: p for p, n in enumerate(nodes) for c in (n.get("children") or [])}


def world_matrices(nodes: list[dict]) -> list[np.ndarray]:
    """(4, 4) every node's transform in scene space."""
    parent = {c: p for p, n in enumerate(nodes) for c in n.get("children", [])}
    cache: dict[int, np.ndarray] = {}

    def world(i: int) -> np.ndarray:
        if i not in cache:
            local = local_matrix(nodes[i])
            cache[i] = world(parent[i]) @ local if i in parent else local
        return cache[i]

    return [world(i) for i in range(len(nodes))]


def mesh_nodes(g: dict, path: str) -> list[int]:
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

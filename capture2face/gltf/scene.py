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


def check_hierarchy(nodes: list, path: str) -> None:
    """The node hierarchy is a forest, as glTF requires: every child index names a node,
    no node has two parents, no node is its own ancestor. A file that breaks it fails here
    in one line (the walks up and down the tree would never end).

    Raises:
        CaptureError: naming the first node at fault.
    """
    parent: dict[int, int] = {}
    for p, node in enumerate(nodes):
        children = (node.get("children") or []) if isinstance(node, dict) else []
        for c in children if isinstance(children, list) else [children]:
            if not isinstance(c, int) or isinstance(c, bool) or not 0 <= c < len(nodes):
                raise CaptureError(f"{path}: node {p} lists child {c!r}, but the file has nodes 0..{len(nodes) - 1}")
            if c in parent:
                raise CaptureError(f"{path}: node {c} is a child of both node {parent[c]} and node {p} "
                                   "(a glTF node has one parent)")
            parent[c] = p
    for start in range(len(nodes)):
        seen, i = {start}, start
        while i in parent:
            i = parent[i]
            if i in seen:
                raise CaptureError(f"{path}: node {i} ({_label(nodes[i])}) is its own ancestor: a cycle in the "
                                   "node hierarchy (glTF nodes form a tree)")
            seen.add(i)


def _label(node) -> str:
    name = node.get("name") if isinstance(node, dict) else None
    return f"'{name}'" if name else "unnamed"


def parents(nodes: list[dict]) -> dict[int, int]:
    """Node index -> its parent's index (roots are absent)."""
    return {c: p for p, n in enumerate(nodes) for c in (n.get("children") or [])}


def world_matrices(nodes: list[dict]) -> list[np.ndarray]:
    """(4, 4) every node's transform in scene space (the hierarchy checked:
    :func:`check_hierarchy`); parents first, without recursion (a chain of thousands of
    nodes is fine)."""
    parent = parents(nodes)
    world: dict[int, np.ndarray] = {}
    for i in range(len(nodes)):
        chain = [i]
        while chain[-1] not in world and chain[-1] in parent:
            chain.append(parent[chain[-1]])
        base = world.get(chain[-1])
        if base is None:  # a root
            base = world[chain[-1]] = local_matrix(nodes[chain[-1]])
        for k in reversed(chain[:-1]):
            base = world[k] = base @ local_matrix(nodes[k])
    return [world[i] for i in range(len(nodes))]


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

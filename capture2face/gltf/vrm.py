"""VRM characters (.vrm: a .glb with VRM's extensions): their expressions as morphs, and
VRM 0.x's facing.

* VRM 0.x (``extensions.VRM``): ``blendShapeMaster.blendShapeGroups``, each with a
  ``presetName`` (``a``, ``blink_l``, ``joy``, ... or ``unknown``), ``binds`` [{mesh,
  index, weight 0-100}], ``materialValues`` and ``isBinary``. The model faces -z:
  :func:`face_forward` turns it half a turn about +y on import (as three-vrm's
  ``rotateVRM0``), so it faces +z as head coordinates do.
* VRM 1.0 (``extensions.VRMC_vrm``): ``expressions.preset`` (``aa``, ``blinkLeft``,
  ``happy``, ...) and ``expressions.custom``, each with ``morphTargetBinds`` [{node, index,
  weight 0-1}], material binds, ``isBinary`` and ``overrideBlink`` / ``overrideLookAt`` /
  ``overrideMouth``.

Each expression with morph binds becomes one morph of the rig, its deltas the bound
targets' weighted sum, named by its preset (else its own name), so the rest of the
pipeline treats it as any morph (:mod:`capture2face.rig.morph_conventions` drives the
presets). A file whose own targets carry ARKit names keeps them (they drive it). Material
binds are not drawn (one warning). :func:`target_weights` turns the expressions' weights
back into the file's own targets' for animation.glb.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.gltf.morphs import Morphs
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.morph_conventions import GROUPS, OVERRIDE_CODES, RULE_GROUP
from capture2face.runtime.log import log

# Half a turn about +y: VRM 0.x's scene (facing -z) -> head coordinates (facing +z).
VRM0_TURN = np.diag([-1.0, 1.0, -1.0])
_TURN_QUAT = np.array([0.0, 1.0, 0.0, 0.0])  # x, y, z, w
VRM_EYE_BONES = "VRM humanoid eye bones"  # FaceRig.eye_source of eyes found by eye_bones


@dataclass(frozen=True)
class Expression:
    """One VRM expression: its name, its binds ((node or mesh index, target index,
    weight 0-1), by node for VRM 1.0, by mesh for 0.x), isBinary, the override codes
    (blink, lookAt, mouth: :data:`OVERRIDE_CODES`) and whether it has material binds."""

    name: str
    binds: tuple[tuple[int, int, float], ...]
    by_node: bool
    is_binary: bool
    overrides: tuple[int, int, int]
    material: bool


def vrm_version(gltf: dict) -> str | None:
    """"1" (VRMC_vrm), "0" (VRM 0.x) or None (not a VRM)."""
    ext = gltf.get("extensions") or {}
    if isinstance(ext.get("VRMC_vrm"), dict):
        return "1"
    if isinstance(ext.get("VRM"), dict):
        return "0"
    return None


def scene_turn(gltf: dict) -> np.ndarray:
    """(3, 3) the rotation from the file's scene axes to the imported rig's."""
    return VRM0_TURN if vrm_version(gltf) == "0" else np.eye(3)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def face_forward(gltf: dict) -> None:
    """Turn a VRM 0.x document's root nodes half a turn about +y, in place (the model then
    faces +z); any other document is left as it is."""
    if vrm_version(gltf) != "0":
        return
    nodes = gltf.get("nodes", [])
    children = {c for n in nodes for c in n.get("children", [])}
    for i, node in enumerate(nodes):
        if i in children:
            continue
        if node.get("matrix"):
            m = np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # column-major
            turn = np.eye(4)
            turn[:3, :3] = VRM0_TURN
            node["matrix"] = [float(v) for v in (turn @ m).T.reshape(-1)]
            continue
        node["translation"] = [float(v) for v in VRM0_TURN @ np.asarray(node.get("translation", [0, 0, 0]), float)]
        node["rotation"] = [float(v) for v in _quat_mul(_TURN_QUAT, np.asarray(node.get("rotation", [0, 0, 0, 1]),
                                                                                float))]


def _code(value) -> int:
    return OVERRIDE_CODES.get(str(value or "none"), 0)


def expressions(gltf: dict) -> list[Expression]:
    """The document's VRM expressions (empty for a file that is not a VRM)."""
    version = vrm_version(gltf)
    out: list[Expression] = []
    if version == "0":
        master = gltf["extensions"]["VRM"].get("blendShapeMaster") or {}
        for group in master.get("blendShapeGroups") or []:
            preset = str(group.get("presetName") or "unknown")
            name = preset if preset.lower() != "unknown" else str(group.get("name") or "")
            binds = tuple((int(b["mesh"]), int(b["index"]), float(b.get("weight", 100)) / 100.0)
                          for b in group.get("binds") or [])
            out.append(Expression(name, binds, False, bool(group.get("isBinary")), (0, 0, 0),
                                  bool(group.get("materialValues"))))
    elif version == "1":
        table = gltf["extensions"]["VRMC_vrm"].get("expressions") or {}
        for kind in ("preset", "custom"):
            for name, e in (table.get(kind) or {}).items():
                binds = tuple((int(b["node"]), int(b["index"]), float(b.get("weight", 1.0)))
                              for b in e.get("morphTargetBinds") or [])
                material = bool(e.get("materialColorBinds") or e.get("textureTransformBinds"))
                overrides = (_code(e.get("overrideBlink")), _code(e.get("overrideLookAt")),
                             _code(e.get("overrideMouth")))
                out.append(Expression(str(name), binds, True, bool(e.get("isBinary")), overrides, material))
    return out


def _group(name: str) -> int:
    key = name.lower()
    return next((column for column, names in GROUPS.items() if key in names), 0)


def expression_morphs(gltf: dict, picked: list[int], parts, morphs: Morphs) -> tuple[Morphs, np.ndarray | None]:
    """The rig's morphs of a VRM (its expressions with morph binds, the module docs) and
    their rules (M, 5) int8 (``FaceRig.morph_rules``); ``morphs`` and None where the file
    is no VRM, has no expression with morph binds, or its targets carry ARKit names.

    Args:
        picked: the drawn mesh nodes; parts: their :class:`~capture2face.gltf.surface.Part`
            (same order); morphs: the targets merged by name.
    """
    exprs = [e for e in expressions(gltf) if e.binds]
    said = sorted(e.name for e in expressions(gltf) if e.material)
    if said:
        log.warning("VRM expressions %s have material binds, which are not drawn (their morph binds are)",
                    ", ".join(said))
    if not exprs or arkit_morphs(morphs.names):
        return morphs, None
    nodes = gltf.get("nodes", [])
    names: list[str] = []
    positions = np.zeros((len(exprs),) + morphs.positions.shape[1:], np.float32)
    normals = np.zeros_like(positions)
    rules = np.zeros((len(exprs), 5), np.int8)
    for k, e in enumerate(exprs):
        name = e.name if e.name not in names else f"{e.name}.{k}"
        names.append(name)
        for ni, part in zip(picked, parts):
            owner = ni if e.by_node else nodes[ni].get("mesh")
            for target, index, weight in e.binds:
                if target == owner and 0 <= index < len(part.morph_positions):
                    positions[k, part.rows] += weight * part.morph_positions[index]
                    normals[k, part.rows] += weight * part.morph_normals[index]
        rules[k, :RULE_GROUP] = (int(e.is_binary), *e.overrides)
        rules[k, RULE_GROUP] = _group(e.name)
    return Morphs(names=names, positions=positions, normals=normals), rules


def target_weights(gltf: dict, node: int, n_targets: int, weights: dict[str, np.ndarray]) -> np.ndarray:
    """(F, n_targets) float32 weights of node ``node``'s own targets: each expression's
    weight (``weights``: {rig morph name: (F,)}, the names :func:`expression_morphs` gave)
    times its binds on the node's mesh, summed and clipped to [0, 1]."""
    frames = len(next(iter(weights.values()))) if weights else 0
    out = np.zeros((frames, n_targets), np.float32)
    mesh = gltf.get("nodes", [])[node].get("mesh")
    taken: list[str] = []
    for k, e in enumerate(x for x in expressions(gltf) if x.binds):
        name = e.name if e.name not in taken else f"{e.name}.{k}"
        taken.append(name)
        if name not in weights:
            continue
        for target, index, weight in e.binds:
            if target == (node if e.by_node else mesh) and 0 <= index < n_targets:
                out[:, index] += weight * weights[name]
    return np.clip(out, 0.0, 1.0)



def _look_at(gltf: dict) -> tuple[str, dict] | None:
    """What turns the gaze ("bone" or "expression") and the lookAt settings that hold its
    range tables: VRM 0.x ``firstPerson`` (``lookAtTypeName`` "Bone" / "BlendShape"), VRM 1.0
    ``lookAt`` (``type`` "bone" / "expression"); None where the file is no VRM."""
    version = vrm_version(gltf)
    if version == "0":
        settings = gltf["extensions"]["VRM"].get("firstPerson") or {}
        kind = str(settings.get("lookAtTypeName") or "Bone").lower()
        return ("expression" if kind == "blendshape" else kind), settings
    if version == "1":
        settings = gltf["extensions"]["VRMC_vrm"].get("lookAt") or {}
        return str(settings.get("type") or "bone").lower(), settings
    return None


def eye_bone_nodes(gltf: dict) -> tuple[int, int] | None:
    """The nodes of the humanoid's ``rightEye`` and ``leftEye`` (the character's own right
    first, as ``FaceRig.eye_centres``); None where the file is no VRM, lacks either, or
    says its gaze turns its look expressions instead (VRM 0.x ``firstPerson.lookAtTypeName``
    "BlendShape", VRM 1.0 ``lookAt.type`` "expression": they turn it, not the bones)."""
    look = _look_at(gltf)
    if look is None or look[0] != "bone":
        return None
    if vrm_version(gltf) == "0":
        human = (gltf["extensions"]["VRM"].get("humanoid") or {}).get("humanBones") or []
        bones = {str(b.get("bone")): b.get("node") for b in human if isinstance(b, dict)}
    else:
        human = (gltf["extensions"]["VRMC_vrm"].get("humanoid") or {}).get("humanBones") or {}
        bones = {str(k): (v or {}).get("node") for k, v in human.items() if isinstance(v, dict)}
    right, left = bones.get("rightEye"), bones.get("leftEye")
    return None if right is None or left is None else (int(right), int(left))


def eye_bones(gltf: dict, bone_nodes: np.ndarray, bone_rest: np.ndarray, skin_joints: np.ndarray,
              skin_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(``eye_centres`` (2, 3) float32, ``eye_vertex_side`` (V,) int8) of a VRM whose
    humanoid eye bones are joints of its skin: each eye bone's bind-pose position
    (``bone_rest``, head cm: VRoid and UniVRM put it at the eyeball's centre) and the
    vertices weighted mostly on it; None otherwise (the eyes then turn by their lookAt
    expressions, where the file has them).

    Args:
        bone_nodes: (B,) each bone's node; skin_joints, skin_weights: (V, 4) bones, weights.
    """
    nodes = eye_bone_nodes(gltf)
    if nodes is None:
        return None
    bones = [np.flatnonzero(np.asarray(bone_nodes) == n) for n in nodes]
    if any(len(b) == 0 for b in bones):
        return None
    side = np.full(len(skin_joints), -1, np.int8)
    for s, b in enumerate(bones):
        side[(skin_weights * (skin_joints == b[0])).sum(1) >= 0.5] = s
    if not ((side == 0).any() and (side == 1).any()):
        return None
    return np.asarray(bone_rest)[[b[0] for b in bones]].astype(np.float32), side


#: Gaze angles (degrees) at which :func:`look_ranges` tabulates the look presets' weights.
LOOK_DEGREES = np.arange(91, dtype=np.float64)


def _hermite(keys: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Unity's AnimationCurve (VRM 0.x's curves): keys (K, 4) time, value, in and out
    tangents; cubic Hermite between keys, held beyond the ends."""
    t = np.clip(t, keys[0, 0], keys[-1, 0])
    k = np.clip(np.searchsorted(keys[:, 0], t, side="right") - 1, 0, max(len(keys) - 2, 0))
    if len(keys) < 2:
        return np.full_like(t, keys[0, 1])
    t0, v0, out0 = keys[k, 0], keys[k, 1], keys[k, 3]
    t1, v1, in1 = keys[k + 1, 0], keys[k + 1, 1], keys[k + 1, 2]
    dt = np.maximum(t1 - t0, 1e-9)
    s = (t - t0) / dt
    return ((2 * s**3 - 3 * s**2 + 1) * v0 + (s**3 - 2 * s**2 + s) * dt * out0
            + (-2 * s**3 + 3 * s**2) * v1 + (s**3 - s**2) * dt * in1)


def _vrm0_map(entry: dict | None) -> np.ndarray:
    """(91,) weights of one VRM 0.x ``lookAt*`` degree map: curve(angle / xRange) * yRange."""
    entry = entry or {}
    curve = np.asarray(entry.get("curve") or [0, 0, 0, 1, 1, 1, 1, 0], np.float64)
    keys = curve[: len(curve) // 4 * 4].reshape(-1, 4) if len(curve) >= 4 else np.array([[0, 0, 0, 1], [1, 1, 1, 0.0]])
    x_range = max(float(entry.get("xRange", 90.0)), 1e-6)
    return float(entry.get("yRange", 1.0)) * _hermite(keys, np.minimum(LOOK_DEGREES / x_range, 1.0))


def _vrm1_map(entry: dict | None) -> np.ndarray:
    """(91,) weights of one VRM 1.0 ``rangeMap*``: outputScale * min(angle / inputMaxValue, 1)."""
    entry = entry or {}
    x_max = max(float(entry.get("inputMaxValue", 90.0)), 1e-6)
    return float(entry.get("outputScale", 1.0)) * np.minimum(LOOK_DEGREES / x_max, 1.0)


def look_ranges(gltf: dict) -> np.ndarray | None:
    """(3, 91) float32 the weights of the look presets at gaze angles :data:`LOOK_DEGREES`
    (rows: LookLeft / LookRight, LookDown, LookUp) from the file's own lookAt range tables,
    clipped to [0, 1]; None where its gaze turns bones (or it is no VRM).

    VRM 0.x: ``firstPerson.lookAtHorizontalOuter`` / ``VerticalDown`` / ``VerticalUp``
    (``curve`` keys of time, value, in, out tangents over angle / ``xRange``, times
    ``yRange``; UniVRM's BlendShape applier reads them, the outer map for both sides).
    VRM 1.0: ``lookAt.rangeMapHorizontalOuter`` / ``VerticalDown`` / ``VerticalUp``
    (``outputScale`` * angle / ``inputMaxValue``, three-vrm's expression applier).
    A map that does not start at 0 is lowered to start there (Godette's horizontal curve
    starts at 0.05, times its ``yRange`` 7.1: 0.36): a gaze straight ahead turns no look
    preset, where UniVRM's would flick the eyes by 0.36 from side to side as the gaze
    crosses the middle."""
    look = _look_at(gltf)
    if look is None or look[0] != "expression":
        return None
    settings = look[1]
    if vrm_version(gltf) == "0":
        keys, table = ("lookAtHorizontalOuter", "lookAtVerticalDown", "lookAtVerticalUp"), _vrm0_map
    else:
        keys, table = ("rangeMapHorizontalOuter", "rangeMapVerticalDown", "rangeMapVerticalUp"), _vrm1_map
    rows = [table(settings.get(k)) for k in keys]
    rows = np.stack(rows)
    return np.clip(rows - rows[:, :1], 0.0, 1.0).astype(np.float32)

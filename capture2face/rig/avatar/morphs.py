"""The default avatar's morph targets: procedural displacement fields on the face's skin,
one builder per group (eyelids, brows, mouth, jaw, cheeks and nose)."""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from capture2face.rig import mesh_ops
from capture2face.rig.avatar.landmarks import BROW_INNER_R, BROW_OUTER_R, BROW_R
from capture2face.rig.avatar.layout import Head, Mouth, Teeth
from capture2face.topology import LIP_INNER_CORNERS, MOUTH_CORNERS


class MorphBuilder:
    """Procedural displacement fields on the skin: prescribed displacements at handle
    vertices, extended biharmonically over the surface within a geodesic radius."""

    def __init__(self, pos: np.ndarray, tris: np.ndarray, normals: np.ndarray):
        self.pos, self.tris, self.normals = pos, tris, normals
        self.n = len(pos)
        self.lap = mesh_ops.uniform_laplacian(self.n, tris)
        self.graph = mesh_ops.edge_graph(pos, tris)

    def distance_to(self, vertices) -> np.ndarray:
        return dijkstra(self.graph, indices=np.asarray(vertices), directed=False, min_only=True)

    def extend(self, handles: dict, radius: float, pinned=()) -> np.ndarray:
        """handles: {vertex id array: (n, 3) or (3,) displacement}; vertices farther
        than ``radius`` from every handle, and ``pinned`` ones, stay still."""
        fixed = np.zeros(self.n, bool)
        values = np.zeros((self.n, 3))
        ids = []
        for idx, disp in handles:
            idx = np.atleast_1d(np.asarray(idx))
            values[idx] = disp
            fixed[idx] = True
            ids.append(idx)
        pinned = np.asarray(list(pinned), dtype=np.int64)
        pinned = pinned[~fixed[pinned]] if len(pinned) else pinned
        fixed[pinned] = True
        values[pinned] = 0.0
        sources = np.concatenate(ids)
        far = (self.distance_to(sources) > radius) & ~np.isin(np.arange(self.n), sources)
        fixed |= far
        values[far] = 0.0
        return mesh_ops.smooth_extension(self.lap, fixed, values, order=2)

    def harmonic(self, fixed: np.ndarray, values: np.ndarray) -> np.ndarray:
        return mesh_ops.smooth_extension(self.lap, fixed, values[:, None], order=1)[:, 0]


def mirror_map(v: np.ndarray) -> np.ndarray:
    """(468,) landmark index of each canonical landmark's mirror image (x -> -x)."""
    _, idx = cKDTree(v).query(v * np.array([-1.0, 1.0, 1.0]))
    return idx


JAW_PIVOT = np.array([0.0, 0.3, -3.0])  # the jaw joints' axis (x) passes through here
JAW_OPEN_RAD = 0.2


def jaw_morphs(points: np.ndarray, amount: np.ndarray) -> dict[str, np.ndarray]:
    """jawOpen (a turn of ``amount`` (N,) x JAW_OPEN_RAD about the jaw axis), jawLeft and
    jawRight deltas (N, 3) of ``points`` (N, 3) that follow the jaw by ``amount``."""
    r = points - JAW_PIVOT
    ang = JAW_OPEN_RAD * amount
    cos, sin = np.cos(ang), np.sin(ang)
    rotated = np.stack([r[:, 0], r[:, 1] * cos - r[:, 2] * sin, r[:, 1] * sin + r[:, 2] * cos], 1)
    return {"jawOpen": rotated - r,
            "jawLeft": amount[:, None] * np.array([0.5, 0.0, 0.0]),
            "jawRight": amount[:, None] * np.array([-0.5, 0.0, 0.0])}


def build_morphs(mb: MorphBuilder, sets: dict, mirror: np.ndarray) -> dict[str, np.ndarray]:
    """All morph targets as (n_skin, 3) displacement fields (cm), group after group (the
    order is the rig's morph order)."""
    eye = sets["eye"]  # side -> dict(upper, lower, ring)
    eye_rings = np.concatenate([eye["L"]["ring"], eye["R"]["ring"]])
    out = _eyelid_morphs(mb, eye)
    out.update(_brow_morphs(mb, mirror, eye_rings))
    out.update(_mouth_corner_morphs(mb, sets, mirror, eye_rings))
    out.update(_pucker_and_funnel(mb, sets))
    # Jaw: the lower face rotates about an axis through the jaw joints.
    out.update(jaw_morphs(mb.pos, sets["lowerness"]))
    out.update(_cheek_and_nose_morphs(mb, sets, mirror, eye_rings, out["mouthPucker"]))
    return out


def _sided(name: str, make, mirror: np.ndarray) -> dict[str, np.ndarray]:
    """{name + "Left", name + "Right"}: make(side_sign, m) -> field for the subject's left
    (+1) or right (-1); m maps a left landmark id to the side's id."""
    return {name + "Left": make(1.0, lambda i: np.asarray(i)),
            name + "Right": make(-1.0, lambda i: mirror[np.asarray(i)])}


def _lid_targets(pos: np.ndarray, e: dict) -> tuple[np.ndarray, np.ndarray]:
    """Blink displacements of one eye ``e``'s upper lid (onto the lower one, meeting 20%
    above it) and lower lid (20% of the way up): ((n upper, 3), (n lower, 3))."""
    lo = e["lower_full"]
    order = np.argsort(pos[lo, 0])

    def at_x(x):
        return np.stack([np.interp(x, pos[lo[order], 0], pos[lo[order], c]) for c in range(3)], 1)

    up = e["upper"]
    lower_under_upper = at_x(pos[up, 0])
    meet = lower_under_upper + 0.2 * (pos[up] - lower_under_upper)
    up_order = np.argsort(pos[e["upper_full"], 0])
    uf = e["upper_full"][up_order]
    upper_over_lower = np.stack([np.interp(pos[e["lower"], 0], pos[uf, 0], pos[uf, c]) for c in range(3)], 1)
    lower_rise = 0.2 * (upper_over_lower - pos[e["lower"]])
    return meet - pos[up], lower_rise


def _eyelid_morphs(mb: MorphBuilder, eye: dict) -> dict[str, np.ndarray]:
    """eyeBlink, eyeWide and eyeSquint, left then right."""
    out: dict[str, np.ndarray] = {}
    # Eyelids: close the upper lid onto the lower one (meeting 20% above the lower lid).
    for s, name in (("L", "Left"), ("R", "Right")):
        e = eye[s]
        d_up, d_lo = _lid_targets(mb.pos, e)
        out["eyeBlink" + name] = mb.extend([(e["upper"], d_up), (e["lower"], d_lo), (e["corners"], 0.0)], 2.2)
        out["eyeWide" + name] = mb.extend(
            [(e["upper"], np.array([0.0, 0.28, 0.04]) * e["upper_profile"][:, None]), (e["lower"], 0.0),
             (e["corners"], 0.0)], 2.2)
        below = e["below"]
        out["eyeSquint" + name] = mb.extend(
            [(e["lower"], np.array([0.0, 0.17, 0.04]) * e["lower_profile"][:, None]),
             (e["upper"], np.array([0.0, -0.08, 0.0]) * e["upper_profile"][:, None]),
             (below, np.array([0.0, 0.2, 0.08]))], 2.5)
    return out


def _brow_morphs(mb: MorphBuilder, mirror: np.ndarray, eye_rings: np.ndarray) -> dict[str, np.ndarray]:
    """browInnerUp, browDown and browOuterUp; the eye contours stay still."""
    # Left landmark lists come from mirroring the right ones.
    brow_l = mirror[BROW_R]
    inner_l, outer_l = mirror[BROW_INNER_R], mirror[BROW_OUTER_R]
    out = {"browInnerUp": mb.extend([(np.concatenate([BROW_INNER_R, inner_l]), np.array([0.0, 0.7, 0.05])),
                                     (9, np.array([0.0, 0.3, 0.0]))], 3.0, pinned=eye_rings)}
    out.update(_sided("browDown", lambda sg, m: mb.extend(
        [(m(brow_l), np.array([0.0, -0.45, 0.05])), (m(inner_l), np.array([-0.25 * sg, -0.45, 0.12]))], 2.5,
        pinned=eye_rings), mirror))
    out.update(_sided("browOuterUp", lambda sg, m: mb.extend([(m(outer_l), np.array([0.0, 0.6, 0.0]))], 2.5,
                                                             pinned=eye_rings), mirror))
    return out


def _mouth_corner_morphs(mb: MorphBuilder, sets: dict, mirror: np.ndarray, eye_rings: np.ndarray
                         ) -> dict[str, np.ndarray]:
    """mouthSmile, mouthFrown, mouthUpperUp and mouthLowerDown, each sided."""
    corner_l = np.array([MOUTH_CORNERS[1], LIP_INNER_CORNERS[1]])
    cheek_l = 425
    out = _sided("mouthSmile", lambda sg, m: mb.extend(
        [(m(corner_l), np.array([0.55 * sg, 0.45, -0.25])), (m(cheek_l), np.array([0.1 * sg, 0.35, 0.15]))],
        3.5, pinned=eye_rings), mirror)
    out.update(_sided("mouthFrown", lambda sg, m: mb.extend([(m(corner_l), np.array([0.05 * sg, -0.45, -0.05]))],
                                                            3.0), mirror))
    upper_l = np.array([267, 269, 270, 312, 311, 310, 302])  # left half of the upper lip
    lower_l = np.array([314, 405, 321, 317, 402, 318])
    out.update(_sided("mouthUpperUp", lambda sg, m: mb.extend([(m(upper_l), np.array([0.0, 0.3, 0.05]))], 2.0,
                                                              pinned=sets["lip_lower"]), mirror))
    out.update(_sided("mouthLowerDown", lambda sg, m: mb.extend([(m(lower_l), np.array([0.0, -0.3, 0.0]))], 2.0,
                                                                pinned=sets["lip_upper"]), mirror))
    return out


def _pucker_and_funnel(mb: MorphBuilder, sets: dict) -> dict[str, np.ndarray]:
    """mouthPucker and mouthFunnel: both lips forward, most at the middle; the funnel
    also parts them."""
    pos = mb.pos
    lips = np.concatenate([sets["lip_upper"], sets["lip_lower"]])
    x = pos[lips, 0]
    half = np.abs(pos[list(MOUTH_CORNERS), 0]).mean()
    centre_weight = np.clip(1.0 - (x / half) ** 2, 0.0, 1.0)
    is_upper = np.isin(lips, sets["lip_upper"])
    press = np.where(is_upper, -0.05, 0.05)
    pucker = np.stack([-0.28 * x, press, 0.1 + 0.45 * centre_weight], 1)
    out = {"mouthPucker": mb.extend([(lips, pucker)], 3.0)}
    inner_upper, inner_lower = sets["lip_inner_upper"], sets["lip_inner_lower"]
    funnel = np.stack([-0.16 * x, np.zeros_like(x), 0.1 + 0.35 * centre_weight], 1)
    gap = np.where(np.isin(lips, inner_upper), 0.25, np.where(np.isin(lips, inner_lower), -0.25, 0.0))
    gap = gap * centre_weight
    funnel[:, 1] += gap + np.where(is_upper, 0.1, -0.1) * centre_weight
    out["mouthFunnel"] = mb.extend([(lips, funnel)], 3.0)
    return out


def _cheek_and_nose_morphs(mb: MorphBuilder, sets: dict, mirror: np.ndarray, eye_rings: np.ndarray,
                           pucker: np.ndarray) -> dict[str, np.ndarray]:
    """cheekPuff (with a little of ``pucker`` (n_skin, 3)) and the sided noseSneer."""
    pos = mb.pos
    # Cheeks puff out along the normal.
    bump = np.zeros(len(pos))
    for cheek in (205, 425):
        centre = pos[cheek] + np.array([0.4 * np.sign(pos[cheek, 0]), -1.6, 0.0])
        d = np.linalg.norm(pos - centre, axis=1)
        bump += np.clip(1 - (d / 3.2) ** 2, 0, 1) ** 2
    out = {"cheekPuff": 0.7 * bump[:, None] * mb.normals + 0.1 * pucker}
    out.update(_sided("noseSneer", lambda sg, m: mb.extend([(m([358, 294, 278]), np.array([0.05 * sg, 0.25, 0.05]))],
                                                           2.0, pinned=np.concatenate([sets["lip_upper"], eye_rings])),
                      mirror))
    return out


def all_morphs(skin_morphs: dict[str, np.ndarray], V: int, mouth: Mouth, teeth: Teeth, head: Head
                ) -> tuple[list[str], np.ndarray]:
    """(morph names, position deltas (M, V, 3)) over all vertices from the skin's
    ``skin_morphs`` (name -> (n_skin, 3))."""
    # Morphs over all vertices: eyes still; mouth interior follows its contour vertex,
    # less so deeper in.
    morph_names = list(skin_morphs)
    attenuation = (1.0 - 0.5 * mouth.depth)[:, None]
    mp = np.zeros((len(morph_names), V, 3))
    for i, name in enumerate(morph_names):
        d = skin_morphs[name]
        inner = d[mouth.src] * attenuation
        inner[mouth.source < 0] = d[mouth.last_ring].mean(0) * attenuation[-1]
        mp[i, :len(d)] = d
        mp[i, mouth.start:mouth.end] = inner
    jaw_follow = jaw_morphs(teeth.verts, (teeth.part > 0).astype(np.float64))
    for name, d in jaw_follow.items():
        if name in morph_names:
            mp[morph_names.index(name), teeth.start:teeth.end] = d
    mp[:, head.start:head.end] = mp[:, head.src] * head.follow[None]
    return morph_names, mp

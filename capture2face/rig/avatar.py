"""The default avatar: a FaceRig built by code from MediaPipe's canonical face mesh.

Built on first use and cached as ``avatar-<variant>-<hash>.rig.npz`` in
``$CAPTURE2FACE_CACHE`` (default ``~/.cache/capture2face``); the hash covers the source of
every builder module, so a code change rebuilds it. Nothing is downloaded.

Vertex layout: canonical vertices 0..467 (vertex i *is* landmark i), then the edge
midpoints of one subdivision step (skin, material 0), then the right and left eyeballs
(material 1), then the mouth interior (material 2), then the upper teeth, lower teeth and
tongue (material 3). The eyeballs turn about their centres with the gaze; the upper teeth
ride the head, the lower teeth and the tongue the jaw bone and the jaw morphs.

Sides are the subject's: ``_L`` bones and ``...Left`` morphs are on the subject's left,
+x in head coordinates, u > 0.5 in texture space.

Bone groups (Dutreve 2009 §5.1: a wrinkle follows a muscle, not one point, and a group's
mean influence is robust to one badly tracked bone), one per muscle system and side: each
brow (frontalis/corrugator sheet: its three bones), each eye (orbicularis oculi: both lids
and the upper cheek below the outer lid, where the crow's feet are), each cheek (zygomatic
and levator: cheek and nose wing, the nasolabial fold), the upper lip, and the lower lip
with the jaw (the chin moves with both). The mouth corners stay alone (a smile can be
one-sided). On 300 tracked synthetic frames (seeds 0-2) these groups lower the per-vertex
influence error from 0.089/0.070/0.088 (brows only) to 0.082/0.060/0.083.
"""

from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.sparse.csgraph import dijkstra

from capture2face.errors import CaptureError
from capture2face.rig import (
    avatar_landmarks,
    avatar_morphs,
    avatar_parts,
    canonical,
    features,
    maps,
    mesh_ops,
)
from capture2face.rig.avatar_landmarks import (
    BROW_R,
    EYE_RINGS,
    LIP_INNER_CORNERS,
    LIP_LOWER_LINES,
    LIP_UPPER_LINES,
)
from capture2face.rig.avatar_morphs import (
    MorphBuilder,
    build_morphs,
    jaw_morphs,
    mirror_map,
)
from capture2face.rig.avatar_parts import (
    FACE_BLEND_RINGS,
    HEAD_RINGS,
    ear,
    eyeball,
    hair_grid,
    head_shell,
    jaw_shadow_grid,
    mouth_interior,
    teeth_and_tongue,
)
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES, FaceRig

VARIANTS = ("default", "wide")


@dataclass(frozen=True)
class BoneSpec:
    name: str
    landmark: int
    radius: float  # cm of geodesic distance from the bone's source beyond which its weight is 0
    group: str
    # The bone's source (weight 1 before normalization): its landmark, plus the skin along
    # segments from it to these (medial, up) offsets in cm (medial = towards the midline).
    # The brows' frontalis sheet carries the forehead above them, and the inner brows
    # pull the glabella between them, so that skin (and its wrinkles' influence) follows
    # the brow bones rather than the head.
    reach: tuple = ()

    @property
    def support(self) -> float:
        """Distance (cm) from the landmark beyond which the bone's weight is 0."""
        return self.radius + max((float(np.hypot(*r)) for r in self.reach), default=0.0)


# Brows: full weight up a 2.5 cm column above each brow bone (and from the inner ones
# down to the glabella's midline), falling off over 3.5 cm around it; the skin within
# FOREHEAD_PIN_CM of the hairline is pinned partly to the head.
_BROW_UP = (0.0, 2.5)
_GLABELLA = (1.05, -0.7)
FOREHEAD_PIN_CM, FOREHEAD_PIN_HEAD = 1.4, 0.5

# (name, landmark, skinning radius). "_R" = subject's right (-x).
BONES = [
    BoneSpec("head", -1, 0.0, "head"),
    BoneSpec("brow_inner_R", 107, 3.5, "brow_R", (_BROW_UP, _GLABELLA)),
    BoneSpec("brow_mid_R", 105, 3.5, "brow_R", (_BROW_UP,)),
    BoneSpec("brow_outer_R", 70, 3.5, "brow_R", (_BROW_UP,)),
    BoneSpec("brow_inner_L", 336, 3.5, "brow_L", (_BROW_UP, _GLABELLA)),
    BoneSpec("brow_mid_L", 334, 3.5, "brow_L", (_BROW_UP,)),
    BoneSpec("brow_outer_L", 300, 3.5, "brow_L", (_BROW_UP,)),
    BoneSpec("eyelid_upper_R", 159, 1.2, "eye_R"), BoneSpec("eyelid_lower_R", 145, 1.2, "eye_R"),
    BoneSpec("eyelid_upper_L", 386, 1.2, "eye_L"), BoneSpec("eyelid_lower_L", 374, 1.2, "eye_L"),
    BoneSpec("cheek_R", 205, 3.2, "cheek_R"), BoneSpec("cheek_L", 425, 3.2, "cheek_L"),
    # Below the outer lower lid: rises in a squint or a smile; reaches the crow's feet.
    BoneSpec("cheek_upper_R", 228, 2.6, "eye_R"), BoneSpec("cheek_upper_L", 448, 2.6, "eye_L"),
    BoneSpec("nose_wing_R", 129, 1.6, "cheek_R"), BoneSpec("nose_wing_L", 358, 1.6, "cheek_L"),
    BoneSpec("lip_upper_R", 82, 1.4, "lip_upper"), BoneSpec("lip_upper_C", 13, 1.4, "lip_upper"),
    BoneSpec("lip_upper_L", 312, 1.4, "lip_upper"),
    BoneSpec("mouth_corner_R", 61, 1.6, ""), BoneSpec("mouth_corner_L", 291, 1.6, ""),
    BoneSpec("lip_lower_R", 87, 1.4, "lip_lower"), BoneSpec("lip_lower_C", 14, 1.4, "lip_lower"),
    BoneSpec("lip_lower_L", 317, 1.4, "lip_lower"),
    BoneSpec("jaw", 152, 8.5, "lip_lower"),
]

# Reference poses as bone displacements (cm) for the subject's left side and the middle;
# "_R" bones get the mirror image (x negated). Every face bone moves in both poses.
_POSES = {
    "stretch": {  # brows raised, eyes wide, mouth open
        "brow_inner": (0.0, 1.0, 0.1), "brow_mid": (0.0, 1.1, 0.05), "brow_outer": (0.0, 0.9, 0.0),
        "eyelid_upper": (0.0, 0.35, 0.05), "eyelid_lower": (0.0, -0.2, 0.0),
        "cheek": (0.0, -0.35, -0.05), "cheek_upper": (0.0, -0.25, 0.0), "nose_wing": (0.0, -0.25, 0.0),
        "lip_upper_C": (0.0, 0.3, 0.0), "lip_upper": (0.0, 0.3, 0.0),
        "mouth_corner": (-0.2, -0.6, -0.1),
        "lip_lower_C": (0.0, -1.0, -0.2), "lip_lower": (0.0, -0.9, -0.2),
        "jaw": (0.0, -0.8, -0.25),
    },
    "compress": {  # brows down and together, squint, lips puckered
        "brow_inner": (-0.35, -0.45, 0.1), "brow_mid": (-0.25, -0.5, 0.05), "brow_outer": (-0.1, -0.45, 0.0),
        "eyelid_upper": (0.0, -0.3, 0.0), "eyelid_lower": (0.0, 0.25, 0.05),
        "cheek": (0.0, 0.4, 0.15), "cheek_upper": (0.0, 0.35, 0.1), "nose_wing": (0.0, 0.3, 0.1),
        "lip_upper_C": (0.0, -0.1, 0.6), "lip_upper": (-0.25, -0.1, 0.55),
        "mouth_corner": (-0.8, 0.0, 0.3),
        "lip_lower_C": (0.0, 0.15, 0.6), "lip_lower": (-0.25, 0.15, 0.55),
        "jaw": (0.0, 0.35, 0.25),
    },
}
# Morph weights shown with each pose (display only; pose evaluation uses bones).
_POSE_MORPHS = {
    "stretch": {"eyeWideLeft": 0.5, "eyeWideRight": 0.5, "jawOpen": 0.3},
    "compress": {"eyeSquintLeft": 0.5, "eyeSquintRight": 0.5, "mouthPucker": 0.5,
                 "browDownLeft": 0.3, "browDownRight": 0.3},
}

# Expression x zone table (Oat's signs: +1 compress map, -1 stretch map). Sided entries
# are written for "Left" and mirrored for "Right".
_ZONE_TABLE = {
    "browInnerUp": {"forehead_left": -1.0, "forehead_right": -1.0, "glabella": -0.5},
    "browOuterUpLeft": {"forehead_left": -1.0},
    "browDownLeft": {"glabella": 0.6, "forehead_left": 0.3},
    "eyeSquintLeft": {"crows_feet_left": 1.0},
    "eyeBlinkLeft": {"crows_feet_left": 0.3},
    "eyeWideLeft": {"forehead_left": -0.4, "crows_feet_left": -0.3},
    "mouthSmileLeft": {"crows_feet_left": 0.5, "nasolabial_left": 1.0},
    "mouthFrownLeft": {"chin": 0.5, "nasolabial_left": -0.3},
    "mouthUpperUpLeft": {"nasolabial_left": 0.5},
    "mouthLowerDownLeft": {"chin": -0.3},
    "noseSneerLeft": {"glabella": 0.5, "nasolabial_left": 0.6},
    "mouthPucker": {"chin": 0.8, "nasolabial_left": -0.3, "nasolabial_right": -0.3},
    "mouthFunnel": {"chin": 0.4},
    "jawOpen": {"chin": -0.6, "nasolabial_left": -0.4, "nasolabial_right": -0.4},
    "cheekPuff": {"nasolabial_left": -0.6, "nasolabial_right": -0.6, "chin": -0.2},
}


def cache_dir() -> Path:
    return Path(os.environ.get("CAPTURE2FACE_CACHE") or Path.home() / ".cache" / "capture2face")


@functools.lru_cache(maxsize=None)
def _source_hash() -> str:
    """Hash of the builder's source files: a code change gives a new cache file."""
    h = hashlib.sha256()
    for module in (canonical, features, mesh_ops, maps, avatar_landmarks, avatar_parts, avatar_morphs,
                   __import__(__name__, fromlist=["x"])):
        h.update(Path(module.__file__).read_bytes())
    h.update(Path(__file__).with_name("face_rig.py").read_bytes())
    return h.hexdigest()[:16]


_MEMO: dict[str, FaceRig] = {}


def _cache_key(variant: str | None) -> str:
    return f"{variant or 'default'}-{_source_hash()}"


def _cache_path(key: str) -> Path:
    return cache_dir() / f"avatar-{key}.rig.npz"


def is_cached(variant: str | None = None) -> bool:
    """Whether :func:`default_avatar` has this variant at hand (in memory or on disk)
    rather than building it (~5 s)."""
    key = _cache_key(variant)
    return key in _MEMO or _cache_path(key).is_file()


def default_avatar(variant: str | None = None) -> FaceRig:
    """The default avatar (``variant=None`` or ``"default"``) or a built-in variant
    (``"wide"``: face 15% wider, brows 0.5 cm higher, longer chin, longer nose: another
    morphology with the same topology, bones and morphs).

    Built on first use and cached on disk and in memory.
    """
    variant = variant or "default"
    if variant not in VARIANTS:
        raise CaptureError(f"unknown avatar variant '{variant}' (choose from {', '.join(VARIANTS)})")
    key = _cache_key(variant)
    if key in _MEMO:
        return _MEMO[key]
    path = _cache_path(key)
    rig = None
    if path.is_file():
        try:
            rig = FaceRig.load(path)
        except CaptureError:
            rig = None  # a corrupt cache file is rebuilt
    if rig is None:
        rig = build_avatar(variant)
        try:
            rig.save(path)
        except OSError:
            pass  # a read-only cache still gives the rig, just not cached
    _MEMO[key] = rig
    return rig


# ---------------------------------------------------------------------------------------
# Geometry


# Inner-lip vertex pairs (upper, lower) that meet when the lips close.
_LIP_PAIRS = [(191, 95), (80, 88), (81, 178), (82, 87), (13, 14), (312, 317), (311, 402), (310, 318), (415, 324)]


def close_lips(v: np.ndarray) -> np.ndarray:
    """(N >= 468, 3) points indexed like MediaPipe's landmarks, with the lips closed.

    The canonical face rests with its lips ~0.5 cm apart; a neutral face has them
    touching. Move the inner lip lines onto their common midline and let the rest of
    each lip follow, fading out over 1 cm."""
    v = v.copy()
    up, lo = np.array(_LIP_PAIRS).T
    half_gap = 0.5 * (v[up] - v[lo])  # (9, 3)
    order = np.argsort(v[up, 0])
    xs = v[up[order], 0]
    for ids, sign, line in ((LIP_UPPER_LINES, -1.0, up), (LIP_LOWER_LINES, 1.0, lo)):
        ids = np.array(ids)
        inner_y = np.interp(v[ids, 0], np.sort(v[line, 0]), v[line[np.argsort(v[line, 0])], 1])
        fade = np.clip(1.0 - np.abs(v[ids, 1] - inner_y) / 1.0, 0.0, 1.0) ** 2
        d = np.stack([np.interp(v[ids, 0], xs, half_gap[order, c]) for c in range(3)], 1)
        v[ids] += sign * d * fade[:, None]
    v[up] = v[lo] = 0.5 * (v[up] + v[lo])  # the inner lines meet exactly
    return v


def _variant_shape(v: np.ndarray, variant: str) -> np.ndarray:
    """Reshape the canonical vertices (468, 3) for a variant; topology is untouched."""
    if variant == "default":
        return v.copy()
    out = v.astype(np.float64).copy()
    x, y = out[:, 0], out[:, 1]
    out[:, 0] = x * 1.15
    out[:, 1] += 0.5 * features.smoothstep((y - 3.2) / 1.2)  # brows and forehead up
    out[:, 1] -= 0.5 * features.smoothstep((-5.5 - y) / 2.5)  # longer chin
    nose = np.exp(-((x / 1.3) ** 2 + ((y + 0.5) / 2.0) ** 2))
    out[:, 2] += 0.3 * nose  # longer nose
    return out


def _remove_hole_fills(triangles: np.ndarray, rings: list[list[int]]) -> np.ndarray:
    """Drop triangles whose three corners lie on one eye or lip contour (the canonical
    mesh closes the eyes and the mouth; the avatar needs them open)."""
    drop = np.zeros(len(triangles), bool)
    for ring in rings:
        drop |= np.isin(triangles, ring).all(axis=1)
    return triangles[~drop]


def _contour_loop(loops: list[np.ndarray], member: int) -> np.ndarray:
    for loop in loops:
        if member in loop:
            return loop
    raise RuntimeError(f"no boundary loop through vertex {member}")


def _split_loop(loop: np.ndarray, a: int, b: int, through: int) -> tuple[np.ndarray, np.ndarray]:
    """Split a closed loop at vertices a and b; return (part containing ``through``,
    the other part), both without the corners."""
    loop = list(loop)
    ia = loop.index(a)
    loop = loop[ia:] + loop[:ia]
    ib = loop.index(b)
    first, second = np.array(loop[1:ib]), np.array(loop[ib + 1:])
    return (first, second) if through in first else (second, first)


# ---------------------------------------------------------------------------------------
# Skinning


def _skin_weights(skin: np.ndarray, graph, loops: list[np.ndarray], lowerness: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic compact-support falloffs, head takes the remainder, top 4 kept. The jaw's
    falloff is broad (the whole lower face follows it) and gated by ``lowerness`` (n_skin,)
    so it never reaches the upper lip.

    Args:
        skin: (n_skin, 3) skin vertex positions; graph: their edge-length graph;
        loops: the skin's boundary loops.
    Returns (joints (n_skin, 4), weights (n_skin, 4))."""
    n_skin = len(skin)
    dist = np.empty((len(BONES) - 1, n_skin))
    for i, b in enumerate(BONES[1:]):
        dist[i] = dijkstra(graph, indices=_bone_source(skin, b), directed=False, min_only=True)
    radius = np.array([b.radius for b in BONES[1:]])[:, None]
    r = np.clip(dist / radius, 0.0, 1.0)
    k = (1.0 - r**2) ** 3  # smooth, 1 on the bone's source, 0 at and beyond the radius
    k[[b.name for b in BONES[1:]].index("jaw")] *= lowerness
    # The hairline stays partly with the head, so a brow raise bunches the forehead's
    # skin below it instead of lifting the face's whole top edge.
    outer = max(loops, key=len)
    top = outer[skin[outer, 1] > skin[list(BROW_R), 1].max()]
    to_top = dijkstra(graph, indices=top, directed=False, min_only=True)
    pin = 1.0 - FOREHEAD_PIN_HEAD * (1.0 - features.smoothstep(to_top / FOREHEAD_PIN_CM))
    k[[i for i, b in enumerate(BONES[1:]) if b.name.startswith("brow")]] *= pin
    total = k.sum(0)
    dense = np.zeros((n_skin, len(BONES)))
    dense[:, 1:] = (k / np.maximum(total, 1.0)).T
    dense[:, 0] = np.maximum(0.0, 1.0 - total)
    return _top4(dense)


def _bone_source(skin: np.ndarray, bone: BoneSpec) -> np.ndarray:
    """Vertices at full weight: the landmark, plus the skin within 0.4 cm (seen from the
    front) of each ``reach`` segment and no farther from the landmark than its end."""
    d = skin - skin[bone.landmark]
    medial = -np.sign(skin[bone.landmark, 0])  # +x for the subject's right side
    source = {bone.landmark}
    for along_x, along_y in bone.reach:
        end = np.array([medial * along_x, along_y])
        t = np.clip(d[:, :2] @ end / (end @ end), 0.0, 1.0)
        near = np.linalg.norm(d[:, :2] - t[:, None] * end, axis=1) < 0.4
        source |= set(np.flatnonzero(near & (np.linalg.norm(d, axis=1) <= np.hypot(*end))).tolist())
    return np.array(sorted(source))


def _top4(dense: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(-dense, axis=1, kind="stable")[:, :4]
    w = np.take_along_axis(dense, order, axis=1)
    w = w / w.sum(1, keepdims=True)
    joints = np.where(w > 0, order, 0).astype(np.int32)
    return joints, w.astype(np.float32)


# ---------------------------------------------------------------------------------------
# The builder: the face's skin, then the parts after it, then skinning, morphs, bones and
# maps over all vertices


@dataclass
class _FaceMesh:
    """The face's skin: the canonical mesh with its eyes and mouth opened, subdivided once
    (n_skin vertices: the canonical ones keep their ids, edge midpoints follow)."""

    canonical_uvs: np.ndarray  # (468, 2) the canonical mesh's UVs (the feature layout's space)
    mirror: np.ndarray  # (468,) each canonical landmark's mirror image
    n_base: int  # canonical vertices; the midpoint of edges[e] is vertex n_base + e
    pos: np.ndarray  # (n_skin, 3)
    tris: np.ndarray  # (T, 3)
    edges: np.ndarray  # (E, 2) the edges that were split
    uvs: np.ndarray  # (n_skin, 2)
    normals: np.ndarray  # (n_skin, 3)
    loops: list  # the skin's boundary loops: eyes, mouth, outer edge


@dataclass
class _Parts:
    """The avatar's vertices part after part: positions, UVs, triangles (numbered over
    the whole avatar as they are added) and a material per vertex."""

    positions: list = field(default_factory=list)
    uvs: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    material: list = field(default_factory=list)
    size: int = 0  # vertices so far

    def add(self, verts: np.ndarray, uvs: np.ndarray, tris: np.ndarray, material: int) -> int:
        """Append a part, its ``tris`` numbered over its own vertices; returns its first
        vertex."""
        start = self.size
        self.positions.append(verts)
        self.uvs.append(uvs)
        self.triangles.append(tris + start)
        self.material.append(np.full(len(verts), material, np.uint8))
        self.size += len(verts)
        return start

    def stack(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(positions (V, 3), uvs (V, 2), triangles (T, 3) int32, material (V,) uint8)."""
        return (np.vstack(self.positions), np.vstack(self.uvs), np.vstack(self.triangles).astype(np.int32),
                np.concatenate(self.material))


@dataclass
class _Eyes:
    """The eyeballs' place among the avatar's vertices and what the rig keeps of them."""

    landmark_vertices: np.ndarray  # (478,) the vertex each tracker landmark sits on
    iris_theta: dict  # side -> the iris rim's polar angle on the eyeball
    centres: list  # [(3,), (3,)] right and left rotation centres
    side: np.ndarray  # (n eye vertices,) int8 0 right, 1 left
    start: int


@dataclass
class _Mouth:
    """The mouth interior's place among the avatar's vertices and where it hangs from."""

    source: np.ndarray  # (N,) contour vertex each mouth vertex copies from (-1 = cap)
    depth: np.ndarray  # (N,) in [0, 1]
    src: np.ndarray  # (N,) source with the cap's -1 as 0
    last_ring: np.ndarray  # contour vertices of the ring before the cap
    start: int
    end: int


@dataclass
class _Teeth:
    """The teeth and tongue's place among the avatar's vertices."""

    verts: np.ndarray  # (K, 3)
    part: np.ndarray  # (K,) 0 upper teeth, 1 lower teeth, 2 tongue
    start: int
    end: int


@dataclass
class _Head:
    """The head shell's place among the avatar's vertices and how it meets the face."""

    verts: np.ndarray  # (H, 3) the head shell
    ring: np.ndarray  # (H,) ring index
    col: np.ndarray  # (H,) column index, n_edge = the copy of column 0
    edge: np.ndarray  # (n_edge,) the face's outer edge loop
    src: np.ndarray  # (H,) the edge vertex each shell vertex follows
    follow: np.ndarray  # (H, 1) how much of that edge vertex's skinning and morphs it takes
    start: int
    end: int

    @property
    def n_edge(self) -> int:
        return len(self.edge)


def build_avatar(variant: str = "default") -> FaceRig:
    """Build the avatar from scratch (no cache). See :func:`default_avatar`."""
    face = _face_mesh(variant)
    mb = MorphBuilder(face.pos, face.tris, face.normals)
    sets = _vertex_sets(face, mb)
    joints, weights = _skin_weights(face.pos, mb.graph, face.loops, sets["lowerness"])
    skin_morphs = build_morphs(mb, sets, face.mirror)

    parts = _Parts()
    parts.add(face.pos, face.uvs, face.tris, 0)
    eyes = _add_eyes(parts, face.pos, sets["eye"])
    mouth = _add_mouth_interior(parts, face.pos, sets)
    teeth = _add_teeth(parts, face.pos, sets["lip_loop"])
    head = _add_head_shell(parts, face.pos, face.loops)
    ears_start = _add_ears(parts, face.pos, head)
    all_pos, all_uv, all_tri, material = parts.stack()
    V = len(all_pos)
    eye_vertex_side = np.full(V, -1, np.int8)
    eye_vertex_side[eyes.start:eyes.start + len(eyes.side)] = eyes.side

    all_joints, all_weights = _part_skinning(joints, weights, mouth, teeth, head, V - ears_start)
    position_ids = _position_ids(V, head)
    morph_names, mp = _all_morphs(skin_morphs, V, mouth, teeth, head)
    rest_normals = _welded_normals(all_pos, all_tri, position_ids)
    morphed_normals = _welded_normals(all_pos[None] + mp, all_tri, position_ids)
    mn = morphed_normals - rest_normals[None]

    return FaceRig(
        name="default" if variant == "default" else f"default_{variant}",
        vertices=_f32(all_pos), normals=_f32(rest_normals), uvs=_f32(all_uv),
        triangles=all_tri, position_ids=position_ids, material=material,
        landmark_vertices=eyes.landmark_vertices,
        skin_joints=all_joints, skin_weights=all_weights,
        morph_names=morph_names, morph_positions=_f32(mp), morph_normals=_f32(mn),
        **_bone_fields(all_pos, morph_names),
        **_map_fields(face, all_pos, all_uv, all_tri, material, rest_normals, eyes.iris_theta, head, morph_names),
        eye_centres=_f32(eyes.centres), eye_vertex_side=eye_vertex_side, double_sided=False,
    )


def _face_mesh(variant: str) -> _FaceMesh:
    """The face's skin of ``variant``: the canonical mesh with its lips closed, reshaped,
    its eyes and mouth opened, subdivided once."""
    mesh = canonical.load_canonical_mesh()
    base = _variant_shape(close_lips(mesh.vertices.astype(np.float64)), variant)
    mirror = mirror_map(mesh.vertices.astype(np.float64))

    # Open the eyes and the mouth, then subdivide once (original vertices keep their ids).
    eye_contours = [[33, 246, 161, 160, 159, 158, 157, 173, 133, 155, 154, 153, 145, 144, 163, 7]]
    eye_contours.append(list(mirror[eye_contours[0]]))
    lip_contour = [78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308, 95, 88, 178, 87, 14, 317, 402, 318, 324]
    tris0 = _remove_hole_fills(mesh.triangles, eye_contours + [lip_contour])
    n0 = mesh_ops.vertex_normals(base, tris0)
    pos, tris, edges = mesh_ops.midpoint_subdivide(base, tris0, n0)
    uvs = np.vstack([mesh.uvs, 0.5 * (mesh.uvs[edges[:, 0]] + mesh.uvs[edges[:, 1]])]).astype(np.float64)
    normals = mesh_ops.vertex_normals(pos, tris)
    return _FaceMesh(canonical_uvs=mesh.uvs, mirror=mirror, n_base=len(base), pos=pos, tris=tris, edges=edges,
                     uvs=uvs, normals=normals, loops=mesh_ops.boundary_loops(tris))


def _vertex_sets(face: _FaceMesh, mb: MorphBuilder) -> dict:
    """Vertex sets: contours (with their new edge vertices), lips, lowerness.

    Keys: "eye" (side -> its contour's parts, :func:`_eye_sets`), "lip_loop" (the inner
    lip contour), "lip_upper", "lip_lower" (each lip's vertices), "lip_inner_upper",
    "lip_inner_lower" (the contour's halves), "lowerness" (n_skin,)."""
    sets: dict = {"eye": _eye_sets(face.pos, face.loops)}
    sets.update(_lip_sets(face))
    sets["lowerness"] = _lowerness(mb, sets)
    return sets


def _eye_sets(pos: np.ndarray, loops: list[np.ndarray]) -> dict:
    """side -> dict(upper, lower, corners, ring, upper_full, lower_full, upper_profile,
    lower_profile, below): each eye's contour split into its lids."""
    eye = {}
    for side, (outer, inner, upper_mark) in EYE_RINGS.items():
        loop = _contour_loop(loops, upper_mark)
        upper, lower = _split_loop(loop, outer, inner, upper_mark)
        corners = np.array([outer, inner])
        prof = lambda ids: np.clip(1 - ((pos[ids, 0] - pos[corners, 0].mean()) / (0.5 * abs(pos[outer, 0] - pos[inner, 0]))) ** 2, 0, 1) ** 0.5
        # Skin just below the lower lid, raised by a squint.
        below_c = pos[lower].mean(0) + np.array([0.0, -0.9, 0.0])
        below = np.argsort(np.linalg.norm(pos - below_c, axis=1))[:3]
        eye[side] = dict(upper=upper, lower=lower, corners=corners, ring=loop,
                         upper_full=np.concatenate([upper, corners]),
                         lower_full=np.concatenate([lower, corners]),
                         upper_profile=prof(upper), lower_profile=prof(lower), below=below)
    return eye


def _lip_sets(face: _FaceMesh) -> dict:
    """The inner lip contour ("lip_loop"), its halves and each lip's vertices."""
    lip_loop = _contour_loop(face.loops, 13)
    inner_upper, inner_lower = _split_loop(lip_loop, *LIP_INNER_CORNERS, 13)
    edge_mid = {tuple(e): face.n_base + i for i, e in enumerate(face.edges.tolist())}

    def with_midpoints(ids):
        ids = set(int(i) for i in ids)
        mids = [m for (a, b), m in edge_mid.items() if a in ids and b in ids]
        return np.array(sorted(ids | set(mids)))

    sets = {"lip_loop": lip_loop}
    sets["lip_upper"] = with_midpoints(LIP_UPPER_LINES + list(inner_upper[inner_upper < face.n_base]))
    sets["lip_lower"] = with_midpoints(LIP_LOWER_LINES + list(inner_lower[inner_lower < face.n_base]))
    sets["lip_upper"] = np.union1d(sets["lip_upper"], inner_upper)
    sets["lip_lower"] = np.union1d(sets["lip_lower"], inner_lower)
    sets["lip_inner_upper"], sets["lip_inner_lower"] = inner_upper, inner_lower
    return sets


def _lowerness(mb: MorphBuilder, sets: dict) -> np.ndarray:
    """(n_skin,) how much each skin vertex goes with the jaw."""
    pos, n_skin = mb.pos, mb.n
    # Lowerness: 1 on the lower lip and jaw, 0 on the upper lip and above, harmonic between
    # (the surface path goes around the mouth, so the lips separate cleanly).
    fixed = np.zeros(n_skin, bool)
    val = np.zeros(n_skin)
    top = pos[:, 1] > pos[[129, 358], 1].mean() - 0.3
    bottom = pos[:, 1] < pos[152, 1] + 2.2
    for ids, value in ((top, 0.0), (sets["lip_upper"], 0.0), (bottom, 1.0), (sets["lip_lower"], 1.0)):
        fixed[ids] = True
        val[ids] = value
    return np.clip(mb.harmonic(fixed, val), 0.0, 1.0)


def _add_eyes(parts: _Parts, pos: np.ndarray, eye_sets: dict) -> _Eyes:
    """The eyeballs (material 1), right then left, behind the skin's eye openings; the
    iris landmarks (468-477) sit on their vertices."""
    landmark_vertices = np.full(478, -1, np.int32)
    landmark_vertices[:468] = np.arange(468)
    start = parts.size
    iris_theta = {}
    eye_centres, eye_side = [], []
    for k, (side, first_landmark) in enumerate((("R", 468), ("L", 473))):
        ring = eye_sets[side]["ring"]
        ev, euv, etri, iris, iris_theta[side], centre = eyeball(pos[ring], side)
        eye_centres.append(centre)
        eye_side.append(np.full(len(ev), k, np.int8))
        offset = parts.add(ev, euv, etri, 1)
        landmark_vertices[first_landmark:first_landmark + 5] = offset + iris
    return _Eyes(landmark_vertices, iris_theta, eye_centres, np.concatenate(eye_side), start)


def _add_mouth_interior(parts: _Parts, pos: np.ndarray, sets: dict) -> _Mouth:
    """The mouth interior (material 2) hanging back from the inner lip contour."""
    lip_loop, inner_upper, inner_lower = sets["lip_loop"], sets["lip_inner_upper"], sets["lip_inner_lower"]
    upperness = np.where(np.isin(lip_loop, inner_upper), 1.0, np.where(np.isin(lip_loop, inner_lower), -1.0, 0.0))
    mv, msource, mdepth, mtri = mouth_interior(lip_loop, pos, upperness)
    # Mouth UVs: angle around the mouth -> angle in the disc, depth -> radius.
    angle = np.arctan2(*(mv[:, :2] - mv[:-1, :2].mean(0)).T[::-1])
    radius = maps.MOUTH_TEXTURE_RADIUS * (0.25 + 0.75 * mdepth)
    mouth_uv = np.array(maps.MOUTH_TEXTURE_CENTRE) + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
    # Both windings: an opening jaw turns some walls away from the camera, and back faces
    # are culled (FaceRig.double_sided False); the bag is dark either way.
    start = parts.add(mv, mouth_uv, np.vstack([mtri, mtri[:, ::-1]]), 2)
    # The cap has no contour vertex of its own: it takes the mean of the last ring's.
    src = np.where(msource >= 0, msource, 0)
    last_ring = msource[-1 - len(lip_loop):-1]
    return _Mouth(msource, mdepth, src, last_ring, start, start + len(mv))


def _add_teeth(parts: _Parts, pos: np.ndarray, lip_loop: np.ndarray) -> _Teeth:
    """Teeth and tongue (material 3) behind the inner lip contour."""
    # Teeth and tongue: the upper teeth ride the head, the lower ones and the tongue the jaw.
    tv, tuv, ttri, tpart = teeth_and_tongue(pos[lip_loop])
    start = parts.add(tv, tuv, ttri, 3)
    return _Teeth(tv, tpart, start, start + len(tv))


def _add_head_shell(parts: _Parts, pos: np.ndarray, loops: list[np.ndarray]) -> _Head:
    """The head beyond the face (material 4) without the ears."""
    # The head beyond the face (material 4): scalp, back of the head and neck grown from
    # the face's outer edge (its first ring shares the edge's positions), then the ears.
    edge = max(loops, key=len)
    hv, hring, hcol, htri = head_shell(pos[edge], pos[152])
    n_edge = len(edge)
    huv = np.stack([maps.HEAD_U[0] + (maps.HEAD_U[1] - maps.HEAD_U[0]) * hcol / n_edge,
                    maps.HEAD_V[0] + (maps.HEAD_V[1] - maps.HEAD_V[0]) * hring / HEAD_RINGS], 1)
    start = parts.add(hv, huv, htri, 4)
    # The head's first rings take the face edge's skinning and morphs, fading to the head bone.
    head_src = edge[hcol % n_edge]
    follow = (1.0 - features.smoothstep(hring / FACE_BLEND_RINGS))[:, None]
    return _Head(hv, hring, hcol, edge, head_src, follow, start, start + len(hv))


def _add_ears(parts: _Parts, pos: np.ndarray, head: _Head) -> int:
    """The ears (material 4) on the head shell's sides, right then left; returns the
    first ear vertex."""
    start = parts.size
    hv, edge = head.verts, head.edge
    ear_y = 0.5 * (pos[[33, 263], 1].mean() + pos[2, 1])  # between eye and nose base levels
    ear_z = float(pos[edge, 2].min()) - 2.2
    for side, (u0, u1) in ((-1.0, maps.EAR_U["R"]), (1.0, maps.EAR_U["L"])):
        near = (np.abs(hv[:, 1] - ear_y) < 1.0) & (np.abs(hv[:, 2] - ear_z) < 1.0) & (hv[:, 0] * side > 0)
        x = float(np.abs(hv[near, 0]).max()) if near.any() else float(np.abs(pos[edge, 0]).max())
        ev, ecoord, efront, etri = ear(np.array([side * (x + 0.35), ear_y, ear_z]), side, 6.0, 3.3)
        r_uv = np.where(efront, 0.5 * ecoord[:, 0], 1.0 - 0.5 * ecoord[:, 0]) * 0.5 * (maps.EAR_V[1] - maps.EAR_V[0])
        a = 2 * np.pi * ecoord[:, 1]
        c = np.array([0.5 * (u0 + u1), 0.5 * (maps.EAR_V[0] + maps.EAR_V[1])])
        parts.add(ev, c + r_uv[:, None] * np.stack([np.cos(a), np.sin(a)], 1), etri, 4)
    return start


def _part_skinning(joints: np.ndarray, weights: np.ndarray, mouth: _Mouth, teeth: _Teeth, head: _Head,
                   n_ears: int) -> tuple[np.ndarray, np.ndarray]:
    """(joints (V, 4) int32, weights (V, 4) float32) of every vertex from the skin's
    ``joints`` and ``weights`` (n_skin, 4).

    Skinning of the extra parts: eyes ride the head; the mouth interior copies the
    contour vertex it hangs from (the cap takes the mean of the last ring)."""
    n_eye = mouth.start - len(joints)
    m_joints, m_weights = joints[mouth.src].copy(), weights[mouth.src].copy()
    cap_dense = np.zeros((1, len(BONES)))
    last_ring = mouth.last_ring
    np.add.at(cap_dense[0], joints[last_ring].ravel(), weights[last_ring].ravel() / len(last_ring))
    cj, cw = _top4(cap_dense)
    m_joints[mouth.source < 0], m_weights[mouth.source < 0] = cj, cw
    # The upper teeth ride the head, the lower ones and the tongue the jaw.
    jaw = [b.name for b in BONES].index("jaw")
    n_teeth = len(teeth.verts)
    t_joints = np.zeros((n_teeth, 4), np.int32)
    t_joints[teeth.part > 0, 0] = jaw
    h_joints, h_weights = _head_skinning(joints, weights, head)
    all_joints = np.vstack([joints, np.zeros((n_eye, 4), np.int32), m_joints, t_joints, h_joints,
                            np.zeros((n_ears, 4), np.int32)]).astype(np.int32)
    eye_w = np.zeros((n_eye + n_teeth + n_ears, 4), np.float32)
    eye_w[:, 0] = 1.0
    all_weights = np.vstack([weights, eye_w[:n_eye], m_weights, eye_w[n_eye:n_eye + n_teeth], h_weights,
                             eye_w[n_eye + n_teeth:]]).astype(np.float32)
    return all_joints, all_weights


def _head_skinning(joints: np.ndarray, weights: np.ndarray, head: _Head) -> tuple[np.ndarray, np.ndarray]:
    """(joints, weights) (H, 4) of the head shell."""
    hv, head_src, follow = head.verts, head.src, head.follow
    # The head's first rings take the face edge's skinning, fading to the head bone.
    h_dense = np.zeros((len(hv), len(BONES)))
    np.add.at(h_dense, (np.repeat(np.arange(len(hv)), 4), joints[head_src].ravel()),
              (follow * weights[head_src]).ravel())
    h_dense[:, 0] += 1.0 - follow[:, 0]
    return _top4(h_dense)


def _position_ids(V: int, head: _Head) -> np.ndarray:
    """(V,) int32 :attr:`FaceRig.position_ids`."""
    # Vertices that share a position: the head's first ring and the face's edge, and each
    # ring's closing copy of its first vertex (UV seams without a shading seam).
    position_ids = np.arange(V, dtype=np.int32)
    n_edge, hring, hcol = head.n_edge, head.ring, head.col
    head_ids = head.start + np.arange(len(head.verts))
    position_ids[head_ids[hcol == n_edge]] = head_ids[hcol == 0]
    position_ids[head_ids[hring == 0]] = head.edge[hcol[hring == 0] % n_edge]
    return position_ids


def _all_morphs(skin_morphs: dict[str, np.ndarray], V: int, mouth: _Mouth, teeth: _Teeth, head: _Head
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


def _bone_fields(all_pos: np.ndarray, morph_names: list[str]) -> dict:
    """The FaceRig's bone and reference-pose fields."""
    # Bones.
    bone_names = [b.name for b in BONES]
    bone_landmarks = np.array([b.landmark for b in BONES], np.int32)
    bone_rest = np.zeros((len(BONES), 3))
    bone_rest[1:] = all_pos[bone_landmarks[1:]]
    group_names = [b.group or b.name for b in BONES]
    bone_groups = np.unique(group_names, return_inverse=True)[1].astype(np.int32)

    pose_names = ["stretch", "compress"]
    pose_bones = np.stack([bone_rest + _pose_displacements(p) for p in pose_names])
    pose_morph_weights = np.zeros((2, len(morph_names)))
    for p, pname in enumerate(pose_names):
        for mname, w in _POSE_MORPHS[pname].items():
            pose_morph_weights[p, morph_names.index(mname)] = w
    return {"bone_names": bone_names, "bone_rest": _f32(bone_rest),
            "bone_parents": np.array([-1] + [0] * (len(BONES) - 1), np.int32),
            "bone_landmarks": bone_landmarks, "bone_groups": bone_groups,
            "pose_names": pose_names, "pose_bones": _f32(pose_bones), "pose_morph_weights": _f32(pose_morph_weights),
            "pose_maps": np.array([0, 1], np.int32), "wrinkle_map_names": ["stretch", "compress"]}


def _map_fields(face: _FaceMesh, all_pos: np.ndarray, all_uv: np.ndarray, all_tri: np.ndarray,
                material: np.ndarray, rest_normals: np.ndarray, iris_theta: dict, head: _Head,
                morph_names: list[str]) -> dict:
    """The FaceRig's tangents, textures, zones and regions."""
    # Regions and zones from one UV layout.
    layout = features.feature_layout(face.canonical_uvs)
    region_weights = features.region_fields(all_uv[:, 0], all_uv[:, 1], layout) * (material == 0)
    zone_table = _zone_table(morph_names)

    tangents = mesh_ops.uv_tangents(all_pos, rest_normals, all_uv, all_tri)
    hv, edge, n_edge, pos = head.verts, head.edge, head.n_edge, face.pos
    textures = maps.build_maps(face.canonical_uvs, all_uv, all_tri, material, iris_theta,
                               head_hair=hair_grid(hv, n_edge),
                               head_shadow=jaw_shadow_grid(hv, n_edge, float(pos[[61, 291], 1].mean())),
                               head_edge_uvs=all_uv[edge[np.arange(n_edge + 1) % n_edge]])
    return {"tangents": _f32(tangents), "albedo": textures["albedo"], "normal_map": textures["normal"],
            "wrinkle_maps": np.stack([textures["stretch"], textures["compress"]]),
            "zone_names": list(ZONE_NAMES), "zone_masks": textures["zones"], "zone_table": _f32(zone_table),
            "region_names": list(REGION_NAMES), "region_weights": _f32(region_weights)}


def _f32(a) -> np.ndarray:
    """``a`` as a contiguous float32 array (what FaceRig stores)."""
    return np.ascontiguousarray(a, dtype=np.float32)


def _welded_normals(positions: np.ndarray, triangles: np.ndarray, position_ids: np.ndarray) -> np.ndarray:
    """Vertex normals (..., V, 3) computed over positions, not vertices: copies of one
    position (a UV seam) share one normal, so no shading seam shows."""
    return mesh_ops.vertex_normals(positions, position_ids[triangles])[..., position_ids, :]


def _pose_displacements(pose: str) -> np.ndarray:
    table = _POSES[pose]
    out = np.zeros((len(BONES), 3))
    for i, b in enumerate(BONES[1:], start=1):
        key = b.name if b.name in table else b.name.rsplit("_", 1)[0]  # "lip_upper_C" or "lip_upper"
        d = np.array(table[key], float)
        if b.name.endswith("_R"):
            d = d * np.array([-1.0, 1.0, 1.0])
        out[i] = d
    return out


def _zone_table(morph_names: list[str]) -> np.ndarray:
    table = np.zeros((len(morph_names), len(ZONE_NAMES)))
    swap = lambda z: z.replace("left", "@").replace("right", "left").replace("@", "right")
    for name, entries in _ZONE_TABLE.items():
        rows = [(name, entries)]
        if name.endswith("Left"):
            rows.append((name[:-4] + "Right", {swap(z): w for z, w in entries.items()}))
        for row_name, row in rows:
            if row_name in morph_names:
                for zone, w in row.items():
                    table[morph_names.index(row_name), ZONE_NAMES.index(zone)] = w
    return table

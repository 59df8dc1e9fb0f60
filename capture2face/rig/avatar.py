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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from capture2face.errors import CaptureError
from capture2face.rig import canonical, features, maps, mesh_ops
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES, FaceRig

VARIANTS = ("default", "wide")

# Eye and lip contours of the canonical mesh (MediaPipe landmark ids).
EYE_RINGS = {  # side: (outer corner, inner corner, upper-lid landmark)
    "R": (33, 133, 159),
    "L": (263, 362, 386),
}
LIP_INNER_CORNERS = (78, 308)
LIP_UPPER_LINES = [61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291,
                   76, 184, 74, 73, 72, 11, 302, 303, 304, 408, 306,
                   62, 183, 42, 41, 38, 12, 268, 271, 272, 407, 292,
                   191, 80, 81, 82, 13, 312, 311, 310, 415]
LIP_LOWER_LINES = [146, 91, 181, 84, 17, 314, 405, 321, 375,
                   77, 90, 180, 85, 16, 315, 404, 320, 307,
                   96, 89, 179, 86, 15, 316, 403, 319, 325,
                   95, 88, 178, 87, 14, 317, 402, 318, 324]
BROW_R = [70, 63, 105, 66, 107, 46, 53, 52, 65, 55]
BROW_INNER_R = [107, 66, 55, 65]
BROW_OUTER_R = [70, 63, 46, 53]


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

IRIS_RADIUS_CM = 0.58


def cache_dir() -> Path:
    return Path(os.environ.get("CAPTURE2FACE_CACHE") or Path.home() / ".cache" / "capture2face")


@functools.lru_cache(maxsize=None)
def _source_hash() -> str:
    """Hash of the builder's source files: a code change gives a new cache file."""
    h = hashlib.sha256()
    for module in (canonical, features, mesh_ops, maps, __import__(__name__, fromlist=["x"])):
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


def _grid_triangles(rows: int, cols: int, closed: bool = False) -> np.ndarray:
    """Triangles of a grid of ``rows`` x ``cols`` vertices numbered row by row (vertex
    ``r * cols + j``): (rows - 1, Q, 2, 3), per quad (r, j) the triangles
    ((r, j), (r+1, j), (r+1, j+1)) and ((r, j), (r+1, j+1), (r, j+1)). ``closed``: each
    row is a ring (Q = cols quads, the last joins column 0), else Q = cols - 1."""
    r = np.arange(rows - 1)[:, None]
    j = np.arange(cols if closed else cols - 1)[None, :]
    j1 = (j + 1) % cols
    a, b, c, d = r * cols + j, (r + 1) * cols + j, (r + 1) * cols + j1, r * cols + j1
    return np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], 2)


def _grid_triangles_by_half(rows: int, cols: int) -> np.ndarray:
    """(T, 3) int32 :func:`_grid_triangles` of an open grid, every quad's first triangle
    (row by row) before every second one: the order the teeth and the head shell were
    built in (the avatar's cached figures depend on the order)."""
    return _grid_triangles(rows, cols).transpose(2, 0, 1, 3).reshape(-1, 3).astype(np.int32)


def _sphere_triangles(n_rings: int, n_around: int, ring_by_ring: bool = False) -> np.ndarray:
    """(T, 3) int32 triangles of a closed sheet with a sphere's topology: vertex 0 a pole,
    then ``n_rings`` rings of ``n_around`` vertices (ring i, vertex j: ``1 + i * n_around
    + j``), then the other pole. Column after column (its first pole's triangle, its quads,
    its last pole's triangle; :func:`_uv_sphere`), or ``ring_by_ring`` (the first pole's
    fan, the quads ring after ring, the last pole's fan; :func:`_ear`)."""
    j = np.arange(n_around)
    j1 = (j + 1) % n_around
    last_ring = 1 + (n_rings - 1) * n_around
    first = np.stack([np.zeros_like(j), 1 + j, 1 + j1], -1)  # (n_around, 3)
    last = np.stack([last_ring + j, np.full_like(j, last_ring + n_around), last_ring + j1], -1)
    quads = 1 + _grid_triangles(n_rings, n_around, closed=True)  # (n_rings - 1, n_around, 2, 3)
    if ring_by_ring:
        return np.concatenate([first, quads.reshape(-1, 3), last]).astype(np.int32)
    columns = quads.transpose(1, 0, 2, 3).reshape(n_around, -1, 3)
    return np.concatenate([first[:, None], columns, last[:, None]], 1).reshape(-1, 3).astype(np.int32)


def _face_outwards(verts: np.ndarray, tris: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """``tris`` (T, 3), reversed if most of them face towards ``inside`` (a point (3,) or
    one per triangle (T, 3)): a closed surface or one strip has one orientation, so the
    majority decides it for all (a few sliver triangles may point either way)."""
    c = verts[tris].mean(1)
    nrm = np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]])
    if ((nrm * (c - inside)).sum(1) < 0).mean() > 0.5:
        return tris[:, ::-1].copy()
    return tris


def _uv_sphere(n_theta: int, n_phi: int):
    """Unit sphere around +z: returns (dirs (N, 3), theta, phi, triangles) with vertex 0
    at the front pole. Ring i has polar angle theta_i; the back pole is the last vertex."""
    thetas = np.linspace(0.0, np.pi, n_theta + 1)[1:-1]
    phis = np.arange(n_phi) * 2 * np.pi / n_phi
    th, ph = np.meshgrid(thetas, phis, indexing="ij")
    theta = np.concatenate([[0.0], th.ravel(), [np.pi]])
    phi = np.concatenate([[0.0], ph.ravel(), [0.0]])
    dirs = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    return dirs, theta, phi, _sphere_triangles(len(thetas), n_phi)


def _eyeball(ring_pos: np.ndarray, side: str):
    """A sphere behind an eye opening whose front silhouette covers the opening and which
    stays behind every lid vertex. Returns (vertices, uvs, triangles, iris vertex ids
    (5,): centre then 4 rim points at phi = 0, 90, 180, 270 degrees, the iris rim's polar
    angle, the sphere's centre (3,): the eye's rotation centre)."""
    centre_xy = 0.5 * (ring_pos[:, :2].max(0) + ring_pos[:, :2].min(0))
    reach = np.linalg.norm(ring_pos[:, :2] - centre_xy, axis=1)
    radius = reach.max() + 0.2
    middle = np.abs(ring_pos[:, 0] - centre_xy[0]) < 0.6
    z_front = ring_pos[middle, 2].min() - 0.12
    cz = z_front - radius
    # Push the sphere back until every contour vertex is at least 0.06 cm in front of it.
    depth_at = lambda c: c + np.sqrt(np.maximum(radius**2 - reach**2, 0.0))
    cz -= max(0.0, float((depth_at(cz) - ring_pos[:, 2] + 0.06).max()))
    centre = np.array([centre_xy[0], centre_xy[1], cz])
    n_phi = 24
    dirs, theta, phi, tris = _uv_sphere(14, n_phi)
    # Put the iris rim on a latitude ring so the iris landmarks sit on vertices.
    iris_theta = np.arcsin(IRIS_RADIUS_CM / radius)
    ring_thetas = np.unique(theta)
    k = int(np.argmin(np.abs(ring_thetas[1:-1] - iris_theta))) + 1
    theta = np.where(np.isclose(theta, ring_thetas[k]), iris_theta, theta)
    dirs = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    verts = centre + radius * dirs

    cu, cv = maps.EYE_TEXTURE_CENTRES[side]
    r_uv = maps.eye_uv_radius(theta)
    uvs = np.stack([cu + r_uv * np.cos(phi), cv - r_uv * np.sin(phi)], 1)
    rim = 1 + (k - 1) * n_phi + np.array([0, 6, 12, 18])
    return verts, uvs, tris, np.concatenate([[0], rim]), iris_theta, centre


def _mouth_interior(lip_loop: np.ndarray, pos: np.ndarray, upper: np.ndarray):
    """A dark cavity hanging back from the inner lip contour: the contour copied, three
    rings shrinking backwards, and a cap. Returns (vertices, source (N,) contour vertex
    each new vertex copies its skinning from (-1 = cap), depth (N,) in [0, 1], triangles
    local to the new vertices). ``upper``: (N,) +1 on the upper lip, -1 on the lower,
    0 at the corners: the bag bulges up behind the upper lip and down behind the lower
    one, so it has volume even with the lips closed."""
    ring = pos[lip_loop]
    c = ring.mean(0)
    half_width = np.abs(ring[:, 0] - c[0]).max()
    across = np.clip(1.0 - ((ring[:, 0] - c[0]) / half_width) ** 2, 0.0, 1.0) ** 0.5
    steps = [(1.0, 1.0, 0.0, 0.0), (0.92, 0.9, 0.5, 0.35), (0.75, 0.8, 1.3, 0.7), (0.45, 0.55, 2.1, 0.6)]
    verts, source, depth = [], [], []
    for sx, sy, dz, bulge in steps:
        y = c[1] + sy * (ring[:, 1] - c[1]) + bulge * upper * across
        verts.append(np.stack([c[0] + sx * (ring[:, 0] - c[0]), y, ring[:, 2] - dz], 1))
        source.append(lip_loop)
        depth.append(np.full(len(lip_loop), dz / 2.5))
    cap = np.array([[c[0], c[1], ring[:, 2].min() - 2.5]])
    verts = np.vstack(verts + [cap])
    source = np.concatenate(source + [[-1]])
    depth = np.concatenate(depth + [[1.0]])
    n = len(lip_loop)
    cap_id = len(verts) - 1
    last = (len(steps) - 1) * n
    cap = [(last + j, cap_id, last + (j + 1) % n) for j in range(n)]
    tris = np.vstack([_grid_triangles(len(steps), n, closed=True).reshape(-1, 3), cap]).astype(np.int32)
    # Face the cavity walls towards a point in front of the mouth (what the camera sees).
    p = verts[tris]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    look = c + np.array([0.0, 0.0, 2.0]) - p.mean(1)
    flip = (normal * look).sum(1) < 0
    tris[flip] = tris[flip][:, ::-1]
    return verts, source, depth, tris


# Upper teeth overlap the lower ones in front (overbite) and stand a little further
# forward (overjet); their widths are maps.TOOTH_WIDTHS.
TEETH = {  # row: (edge y offset from the lip line, height up (+) or down (-), z back from the upper row)
    "upper": (-0.22, 1.1, 0.0),
    "lower": (-0.1, -0.9, 0.14),
}
TEETH_BEHIND_LIPS_CM = 0.42  # the upper incisors' front behind the inner lip contour
TOOTH_THICKNESS = 0.28


def _teeth_row(front: np.ndarray, edge_y: float, height: float, back_dir: np.ndarray):
    """One row of teeth as a strip folded over the biting edge: the front face (root,
    middle, edge), then the back face (edge, middle, root). ``front`` (N, 3) points along
    the arch on the front face, ``back_dir`` (N, 3) unit vectors into the mouth.
    Returns (vertices (6N, 3), row fraction (6N,) from 0 at the front root to 1 at the back
    root, triangles (local), core (6N, 3): the middle of the tooth behind each vertex, for
    facing the triangles outwards)."""
    n = len(front)
    rows = []
    for up, back in ((1.0, 0.0), (0.5, 0.0), (0.0, 0.0), (0.0, 1.0), (0.5, 1.0), (1.0, 1.0)):
        p = front + back * TOOTH_THICKNESS * back_dir
        p[:, 1] = edge_y + up * height
        rows.append(p)
    core = front + 0.5 * TOOTH_THICKNESS * back_dir
    core[:, 1] = edge_y + 0.5 * height
    tris = _grid_triangles_by_half(6, n)
    return np.concatenate(rows), np.repeat(np.arange(6) / 5.0, n), tris, np.tile(core, (6, 1))


def _teeth_and_tongue(ring: np.ndarray):
    """Upper and lower teeth along a dental arch behind the inner lip contour ``ring``
    (N, 3), and a tongue on the floor of the mouth behind the lower teeth.

    Returns (vertices (K, 3), uvs (K, 2), triangles (local), part (K,): 0 upper teeth,
    1 lower teeth, 2 tongue)."""
    lip_y = float(ring[np.argmax(ring[:, 2]), 1])  # the lips meet here on the midline
    z_front = float(ring[:, 2].max()) - TEETH_BEHIND_LIPS_CM
    half = float(np.abs(ring[:, 0]).max())
    # The arch: a parabola from the front teeth to just inside the lip corners, 1.3 cm
    # further back at the corners than at the front (what a dental arch does).
    ends = sum(maps.TOOTH_WIDTHS)
    xs = np.linspace(-1.0, 1.0, 41)
    curve = lambda x, dz: np.stack([x * (half - 0.15), np.zeros_like(x), z_front - dz - 1.3 * x**2], 1)
    verts, uvs, tris, part = [], [], [], []
    offset = 0
    for k, (row, (edge_dy, height, back)) in enumerate(TEETH.items()):
        front = curve(xs, back)
        # Arc length from the midline, for the texture's tooth boundaries.
        seg = np.linalg.norm(np.diff(front, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        arc -= arc[len(xs) // 2]
        tangent = np.gradient(front, axis=0)
        back_dir = np.cross(tangent, [0.0, 1.0, 0.0])
        back_dir /= np.linalg.norm(back_dir, axis=1, keepdims=True)
        back_dir *= -np.sign(back_dir[len(xs) // 2, 2])  # into the mouth (-z at the front)
        v, frac, t, core = _teeth_row(front, lip_y + edge_dy, height, back_dir)
        t = _face_outwards(v, t, core[t[:, 0]])  # away from the tooth's core
        u = maps.TEETH_U[0] + (maps.TEETH_U[1] - maps.TEETH_U[0]) * (0.5 + 0.5 * np.tile(arc, 6) / ends)
        v0, v1 = maps.TEETH_V[row]
        uvs.append(np.stack([u, v0 + (v1 - v0) * frac], 1))
        verts.append(v)
        tris.append(t + offset)
        part.append(np.full(len(v), k))
        offset += len(v)
    # Tongue: the upper half of a flattened ellipsoid resting behind the lower teeth.
    dirs, _, _, ttri = _uv_sphere(8, 20)
    radii = np.array([half - 0.55, 0.5, 1.5])
    centre = np.array([0.0, lip_y - 0.75, z_front - 0.14 - TOOTH_THICKNESS - 0.1 - radii[2]])
    # The sphere is around +z; turn it so its poles point along y (up).
    d = np.stack([dirs[:, 0], dirs[:, 2], -dirs[:, 1]], 1)
    tv = centre + radii * d
    tv[:, 1] = np.maximum(tv[:, 1], centre[1] - 0.1)  # flat underside
    tu = maps.TONGUE_UV[0] + (maps.TONGUE_UV[1] - maps.TONGUE_UV[0]) * (0.5 + 0.5 * d[:, 0])
    tvv = maps.TONGUE_UV[2] + (maps.TONGUE_UV[3] - maps.TONGUE_UV[2]) * (0.5 - 0.5 * d[:, 2])
    ttri = _face_outwards(tv, ttri, centre)
    verts.append(tv)
    uvs.append(np.stack([tu, tvv], 1))
    tris.append(ttri + offset)
    part.append(np.full(len(tv), 2))
    return np.vstack(verts), np.vstack(uvs), np.vstack(tris).astype(np.int32), np.concatenate(part)


# Head: the scalp, the back of the head and the neck grow from the face mask's outer
# edge in HEAD_RINGS rings towards a pole behind and below the head; ears sit on the sides.
# 14 rings (9.4k triangles in all, 4.8k vertices) instead of 28 (11.4k, 5.8k): the head's
# smooth curvature shows no facets at run's framing, and a frame costs 2-4% less CPU on
# llvmpipe (its per-pixel work is most of a frame; the NumPy deformation is per vertex).
HEAD_RINGS = 14
HEAD_POLE = np.array([0.0, -0.35, -1.0]) / np.hypot(0.35, 1.0)
FACE_BLEND_RINGS = 3  # rings over which the face edge's own shape, skinning and morphs fade out
# The neck ends here (cm): out of a synthetic clip's frame below the chin even with the
# head tipped back, and within 32 cm of the origin (a glTF's float32 metres give the
# centimetres back within 2e-6 there).
NECK_BOTTOM_Y = -27.0


def _ellipsoid_exit(origin: np.ndarray, d: np.ndarray, centre: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(N,) distance along unit rays ``d`` (N, 3) from ``origin`` (inside) to an ellipsoid."""
    o, dd = (origin - centre) / radii, d / radii
    a, b, c = (dd * dd).sum(1), 2 * (o * dd).sum(1), (o * o).sum() - 1.0
    return (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * a)


def _neck_exit(origin: np.ndarray, d: np.ndarray, axis_xz: np.ndarray, radii_xz: np.ndarray, bottom: float,
               top: float) -> np.ndarray:
    """(N,) distance along rays ``d`` from ``origin`` (inside) to a vertical elliptic
    cylinder (axis through ``axis_xz``, radii ``radii_xz``) cut at y = ``bottom`` and ``top``."""
    o = (origin[[0, 2]] - axis_xz) / radii_xz
    dd = d[:, [0, 2]] / radii_xz
    a, b, c = (dd * dd).sum(1), 2 * (dd @ o), (o * o).sum() - 1.0
    side = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / np.maximum(2 * a, 1e-12)
    side = np.where(a > 1e-12, side, np.inf)
    cap = np.where(d[:, 1] < -1e-9, (bottom - origin[1]) / np.minimum(d[:, 1], -1e-9),
                   np.where(d[:, 1] > 1e-9, (top - origin[1]) / np.maximum(d[:, 1], 1e-9), np.inf))
    return np.minimum(side, cap)


def _head_shell(edge: np.ndarray, chin: np.ndarray):
    """The head beyond the face: rings grown from the face's outer edge loop ``edge``
    (N, 3) towards :data:`HEAD_POLE`, on the smooth union of a skull ellipsoid and a neck
    cylinder sized from the face, bent at the edge to meet the face exactly.

    Returns (vertices (HEAD_RINGS * (N + 1) + 1, 3) ring by ring, the first ring the edge
    itself, each ring closed by a copy of its first vertex, then the pole; ring index (per
    vertex, HEAD_RINGS for the pole); column index (0..N, N = the copy of 0); triangles
    (local))."""
    n = len(edge)
    half_width = float(np.abs(edge[:, 0]).max())
    centre = np.array([0.0, 0.25 * half_width, edge[:, 2].min() - 0.1 * half_width])
    radii = np.array([1.03, 1.38, 1.35]) * half_width
    neck_axis = np.array([0.0, centre[2] - 0.18 * half_width])
    neck_radii = np.array([0.64, 0.58]) * half_width  # the throat ~5 cm behind the chin
    origin = centre + np.array([0.0, -0.2 * half_width, 0.0])
    bottom = min(NECK_BOTTOM_Y, float(chin[1]) - 4.0)

    def radius(d):
        a = _ellipsoid_exit(origin, d, centre, radii)
        b = _neck_exit(origin, d, neck_axis, neck_radii, bottom, float(centre[1]))
        k = 0.12 * half_width  # a soft fillet where the neck meets the skull
        return 0.5 * (a + b + np.sqrt((a - b) ** 2 + k * k))

    rel = edge - origin
    rho = np.linalg.norm(rel, axis=1)
    d0 = rel / rho[:, None]
    gap = rho - radius(d0)  # the face's edge against the smooth head: bent away over the first rings
    rings, ring_ids, cols = [], [], []
    for k in range(HEAD_RINGS):
        t = k / HEAD_RINGS
        # Slerp from the edge direction to the pole (never through the face).
        omega = np.arccos(np.clip(d0 @ HEAD_POLE, -1.0, 1.0))[:, None]
        so = np.maximum(np.sin(omega), 1e-9)
        d = (np.sin((1 - t) * omega) * d0 + np.sin(t * omega) * HEAD_POLE) / so
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        fade = 1.0 - features.smoothstep(np.full(1, k / FACE_BLEND_RINGS))[0]
        p = origin + d * (radius(d) + gap * fade)[:, None]
        if k == 0:
            p = edge.copy()
        rings.append(np.vstack([p, p[:1]]))
        ring_ids.append(np.full(n + 1, k))
        cols.append(np.arange(n + 1))
    pole = origin + HEAD_POLE * radius(HEAD_POLE[None])[0]  # the rings close on one vertex
    verts = np.vstack(rings + [pole[None]])
    last, pole_id = (HEAD_RINGS - 1) * (n + 1), len(verts) - 1
    cap = [(last + j, pole_id, last + j + 1) for j in range(n)]
    tris = np.vstack([_grid_triangles_by_half(HEAD_RINGS, n + 1), np.array(cap, np.int32)])
    tris = _face_outwards(verts, tris, origin)  # away from the head's inside
    return verts, np.concatenate(ring_ids + [[HEAD_RINGS]]), np.concatenate(cols + [[n // 2]]), tris


def _ear(centre: np.ndarray, side: float, height: float, width: float):
    """An ear: a thin shell (outer face with a raised rim and a hollow concha, folded at
    the rim onto its back) centred at ``centre``, facing outwards (``side`` = +1: +x) and
    a little forwards. Returns (vertices, (radius, angle) per vertex in [0, 1] x [0, 1)
    for the texture, front (bool per vertex), triangles (local))."""
    n_r, n_a = 7, 24
    rs = np.linspace(0.0, 1.0, n_r)[1:]  # the centre is one vertex per face
    angles = np.arange(n_a) * 2 * np.pi / n_a
    out = np.array([side * np.cos(0.35), 0.0, np.sin(0.35)])  # outward, turned 20 degrees forwards
    up = np.array([0.0, 1.0, 0.0])
    along = np.cross(up, out) * side  # towards the back of the head
    depth = lambda r: 0.45 * np.exp(-((r - 0.88) / 0.1) ** 2) - 0.35 * np.exp(-((r - 0.35) / 0.2) ** 2)
    thick = 0.45
    verts, coords, front = [centre + out * depth(0.0)], [(0.0, 0.0)], [True]
    for face in (0, 1):
        for r in (rs if face == 0 else rs[::-1]):
            for a in angles:
                w = width * (1.0 + 0.15 * np.sin(a))  # a slightly pear-shaped outline: wider at the top
                p = centre + r * (0.5 * w * np.cos(a) * along + 0.5 * height * np.sin(a) * up)
                verts.append(p + out * (depth(r) if face == 0 else -thick * (1.0 - r**4)))
                coords.append((r, a / (2 * np.pi)))
                front.append(face == 0)
    verts.append(centre - out * thick)
    coords.append((0.0, 0.0))
    front.append(False)
    verts, coords, front = np.array(verts), np.array(coords), np.array(front)
    tris = _sphere_triangles(2 * len(rs), n_a, ring_by_ring=True)  # a sphere folded flat
    nrm = np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]])
    is_front = front[tris].all(1)
    if ((nrm[is_front] @ out) < 0).mean() > 0.5:  # one folded sheet: the front faces out
        tris = tris[:, ::-1].copy()
    return verts, coords, front, tris


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
# Morph targets


class _MorphBuilder:
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


def _mirror_map(v: np.ndarray) -> np.ndarray:
    """(468,) landmark index of each canonical landmark's mirror image (x -> -x)."""
    _, idx = cKDTree(v).query(v * np.array([-1.0, 1.0, 1.0]))
    return idx


JAW_PIVOT = np.array([0.0, 0.3, -3.0])  # the jaw joints' axis (x) passes through here
JAW_OPEN_RAD = 0.2


def _jaw_morphs(points: np.ndarray, amount: np.ndarray) -> dict[str, np.ndarray]:
    """jawOpen (a turn of ``amount`` (N,) x JAW_OPEN_RAD about the jaw axis), jawLeft and
    jawRight deltas (N, 3) of ``points`` (N, 3) that follow the jaw by ``amount``."""
    r = points - JAW_PIVOT
    ang = JAW_OPEN_RAD * amount
    cos, sin = np.cos(ang), np.sin(ang)
    rotated = np.stack([r[:, 0], r[:, 1] * cos - r[:, 2] * sin, r[:, 1] * sin + r[:, 2] * cos], 1)
    return {"jawOpen": rotated - r,
            "jawLeft": amount[:, None] * np.array([0.5, 0.0, 0.0]),
            "jawRight": amount[:, None] * np.array([-0.5, 0.0, 0.0])}


def _build_morphs(mb: _MorphBuilder, sets: dict, mirror: np.ndarray) -> dict[str, np.ndarray]:
    """All morph targets as (n_skin, 3) displacement fields (cm)."""
    pos = mb.pos
    out: dict[str, np.ndarray] = {}

    def sided(name: str, make):
        """make(side_sign, m) -> field for the subject's left (+1) or right (-1); m maps a
        left landmark id to the side's id."""
        out[name + "Left"] = make(1.0, lambda i: np.asarray(i))
        out[name + "Right"] = make(-1.0, lambda i: mirror[np.asarray(i)])

    eye = sets["eye"]  # side -> dict(upper, lower, ring)
    # Eyelids: close the upper lid onto the lower one (meeting 20% above the lower lid).
    def lid_targets(s):
        e = eye[s]
        lo = e["lower_full"]
        order = np.argsort(pos[lo, 0])
        at_x = lambda x: np.stack([np.interp(x, pos[lo[order], 0], pos[lo[order], c]) for c in range(3)], 1)
        up = e["upper"]
        lower_under_upper = at_x(pos[up, 0])
        meet = lower_under_upper + 0.2 * (pos[up] - lower_under_upper)
        up_order = np.argsort(pos[e["upper_full"], 0])
        uf = e["upper_full"][up_order]
        upper_over_lower = np.stack([np.interp(pos[e["lower"], 0], pos[uf, 0], pos[uf, c]) for c in range(3)], 1)
        lower_rise = 0.2 * (upper_over_lower - pos[e["lower"]])
        return meet - pos[up], lower_rise

    for s, name in (("L", "Left"), ("R", "Right")):
        e = eye[s]
        d_up, d_lo = lid_targets(s)
        out["eyeBlink" + name] = mb.extend([(e["upper"], d_up), (e["lower"], d_lo), (e["corners"], 0.0)], 2.2)
        out["eyeWide" + name] = mb.extend(
            [(e["upper"], np.array([0.0, 0.28, 0.04]) * e["upper_profile"][:, None]), (e["lower"], 0.0), (e["corners"], 0.0)], 2.2)
        below = e["below"]
        out["eyeSquint" + name] = mb.extend(
            [(e["lower"], np.array([0.0, 0.17, 0.04]) * e["lower_profile"][:, None]),
             (e["upper"], np.array([0.0, -0.08, 0.0]) * e["upper_profile"][:, None]),
             (below, np.array([0.0, 0.2, 0.08]))], 2.5)

    # Brows. Left landmark lists come from mirroring the right ones.
    brow_l = mirror[BROW_R]
    inner_l, outer_l = mirror[BROW_INNER_R], mirror[BROW_OUTER_R]
    eye_rings = np.concatenate([eye["L"]["ring"], eye["R"]["ring"]])
    out["browInnerUp"] = mb.extend([(np.concatenate([BROW_INNER_R, inner_l]), np.array([0.0, 0.7, 0.05])),
                                    (9, np.array([0.0, 0.3, 0.0]))], 3.0, pinned=eye_rings)
    sided("browDown", lambda sg, m: mb.extend(
        [(m(brow_l), np.array([0.0, -0.45, 0.05])), (m(inner_l), np.array([-0.25 * sg, -0.45, 0.12]))], 2.5,
        pinned=eye_rings))
    sided("browOuterUp", lambda sg, m: mb.extend([(m(outer_l), np.array([0.0, 0.6, 0.0]))], 2.5, pinned=eye_rings))

    # Mouth.
    corner_l = np.array([291, 308])
    cheek_l = 425
    sided("mouthSmile", lambda sg, m: mb.extend(
        [(m(corner_l), np.array([0.55 * sg, 0.45, -0.25])), (m(cheek_l), np.array([0.1 * sg, 0.35, 0.15]))],
        3.5, pinned=eye_rings))
    sided("mouthFrown", lambda sg, m: mb.extend([(m(corner_l), np.array([0.05 * sg, -0.45, -0.05]))], 3.0))
    upper_l = np.array([267, 269, 270, 312, 311, 310, 302])  # left half of the upper lip
    lower_l = np.array([314, 405, 321, 317, 402, 318])
    sided("mouthUpperUp", lambda sg, m: mb.extend([(m(upper_l), np.array([0.0, 0.3, 0.05]))], 2.0,
                                                  pinned=sets["lip_lower"]))
    sided("mouthLowerDown", lambda sg, m: mb.extend([(m(lower_l), np.array([0.0, -0.3, 0.0]))], 2.0,
                                                    pinned=sets["lip_upper"]))
    lips = np.concatenate([sets["lip_upper"], sets["lip_lower"]])
    x = pos[lips, 0]
    half = np.abs(pos[[61, 291], 0]).mean()
    centre_weight = np.clip(1.0 - (x / half) ** 2, 0.0, 1.0)
    is_upper = np.isin(lips, sets["lip_upper"])
    press = np.where(is_upper, -0.05, 0.05)
    pucker = np.stack([-0.28 * x, press, 0.1 + 0.45 * centre_weight], 1)
    out["mouthPucker"] = mb.extend([(lips, pucker)], 3.0)
    inner_upper, inner_lower = sets["lip_inner_upper"], sets["lip_inner_lower"]
    funnel = np.stack([-0.16 * x, np.zeros_like(x), 0.1 + 0.35 * centre_weight], 1)
    gap = np.where(np.isin(lips, inner_upper), 0.25, np.where(np.isin(lips, inner_lower), -0.25, 0.0))
    gap = gap * centre_weight
    funnel[:, 1] += gap + np.where(is_upper, 0.1, -0.1) * centre_weight
    out["mouthFunnel"] = mb.extend([(lips, funnel)], 3.0)

    # Jaw: the lower face rotates about an axis through the jaw joints.
    s = sets["lowerness"]
    out.update(_jaw_morphs(pos, s))

    # Cheeks puff out along the normal.
    bump = np.zeros(len(pos))
    for cheek in (205, 425):
        centre = pos[cheek] + np.array([0.4 * np.sign(pos[cheek, 0]), -1.6, 0.0])
        d = np.linalg.norm(pos - centre, axis=1)
        bump += np.clip(1 - (d / 3.2) ** 2, 0, 1) ** 2
    out["cheekPuff"] = 0.7 * bump[:, None] * mb.normals + 0.1 * out["mouthPucker"]
    sided("noseSneer", lambda sg, m: mb.extend([(m([358, 294, 278]), np.array([0.05 * sg, 0.25, 0.05]))], 2.0,
                                               pinned=np.concatenate([sets["lip_upper"], eye_rings])))
    return out


# ---------------------------------------------------------------------------------------
# The builder


def build_avatar(variant: str = "default") -> FaceRig:
    """Build the avatar from scratch (no cache). See :func:`default_avatar`."""
    mesh = canonical.load_canonical_mesh()
    base = _variant_shape(close_lips(mesh.vertices.astype(np.float64)), variant)
    mirror = _mirror_map(mesh.vertices.astype(np.float64))

    # Open the eyes and the mouth, then subdivide once (original vertices keep their ids).
    eye_contours = [[33, 246, 161, 160, 159, 158, 157, 173, 133, 155, 154, 153, 145, 144, 163, 7]]
    eye_contours.append(list(mirror[eye_contours[0]]))
    lip_contour = [78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308, 95, 88, 178, 87, 14, 317, 402, 318, 324]
    tris0 = _remove_hole_fills(mesh.triangles, eye_contours + [lip_contour])
    n0 = mesh_ops.vertex_normals(base, tris0)
    pos, tris, edges = mesh_ops.midpoint_subdivide(base, tris0, n0)
    uvs = np.vstack([mesh.uvs, 0.5 * (mesh.uvs[edges[:, 0]] + mesh.uvs[edges[:, 1]])]).astype(np.float64)
    n_skin = len(pos)
    normals = mesh_ops.vertex_normals(pos, tris)

    # Vertex sets: contours (with their new edge vertices), lips, lowerness.
    loops = mesh_ops.boundary_loops(tris)
    sets: dict = {"eye": {}}
    for side, (outer, inner, upper_mark) in EYE_RINGS.items():
        loop = _contour_loop(loops, upper_mark)
        upper, lower = _split_loop(loop, outer, inner, upper_mark)
        corners = np.array([outer, inner])
        prof = lambda ids: np.clip(1 - ((pos[ids, 0] - pos[corners, 0].mean()) / (0.5 * abs(pos[outer, 0] - pos[inner, 0]))) ** 2, 0, 1) ** 0.5
        # Skin just below the lower lid, raised by a squint.
        below_c = pos[lower].mean(0) + np.array([0.0, -0.9, 0.0])
        below = np.argsort(np.linalg.norm(pos - below_c, axis=1))[:3]
        sets["eye"][side] = dict(upper=upper, lower=lower, corners=corners, ring=loop,
                                 upper_full=np.concatenate([upper, corners]),
                                 lower_full=np.concatenate([lower, corners]),
                                 upper_profile=prof(upper), lower_profile=prof(lower), below=below)
    lip_loop = _contour_loop(loops, 13)
    inner_upper, inner_lower = _split_loop(lip_loop, *LIP_INNER_CORNERS, 13)
    edge_mid = {tuple(e): len(base) + i for i, e in enumerate(edges.tolist())}

    def with_midpoints(ids):
        ids = set(int(i) for i in ids)
        mids = [m for (a, b), m in edge_mid.items() if a in ids and b in ids]
        return np.array(sorted(ids | set(mids)))

    sets["lip_upper"] = with_midpoints(LIP_UPPER_LINES + list(inner_upper[inner_upper < len(base)]))
    sets["lip_lower"] = with_midpoints(LIP_LOWER_LINES + list(inner_lower[inner_lower < len(base)]))
    sets["lip_upper"] = np.union1d(sets["lip_upper"], inner_upper)
    sets["lip_lower"] = np.union1d(sets["lip_lower"], inner_lower)
    sets["lip_inner_upper"], sets["lip_inner_lower"] = inner_upper, inner_lower

    mb = _MorphBuilder(pos, tris, normals)
    # Lowerness: 1 on the lower lip and jaw, 0 on the upper lip and above, harmonic between
    # (the surface path goes around the mouth, so the lips separate cleanly).
    fixed = np.zeros(n_skin, bool)
    val = np.zeros(n_skin)
    top = pos[:, 1] > pos[[129, 358], 1].mean() - 0.3
    bottom = pos[:, 1] < pos[152, 1] + 2.2
    for ids, value in ((top, 0.0), (sets["lip_upper"], 0.0), (bottom, 1.0), (sets["lip_lower"], 1.0)):
        fixed[ids] = True
        val[ids] = value
    sets["lowerness"] = np.clip(mb.harmonic(fixed, val), 0.0, 1.0)

    joints, weights = _skin_weights(pos, mb.graph, loops, sets["lowerness"])
    skin_morphs = _build_morphs(mb, sets, mirror)

    # Eyes and mouth interior.
    parts_pos, parts_uv, parts_tri, parts_mat = [pos], [uvs], [tris], [np.zeros(n_skin, np.uint8)]
    landmark_vertices = np.full(478, -1, np.int32)
    landmark_vertices[:468] = np.arange(468)
    offset = n_skin
    iris_theta = {}
    eye_centres, eye_side = [], []
    for k, (side, first_landmark) in enumerate((("R", 468), ("L", 473))):
        ring = sets["eye"][side]["ring"]
        ev, euv, etri, iris, iris_theta[side], centre = _eyeball(pos[ring], side)
        eye_centres.append(centre)
        eye_side.append(np.full(len(ev), k, np.int8))
        parts_pos.append(ev)
        parts_uv.append(euv)
        parts_tri.append(etri + offset)
        parts_mat.append(np.ones(len(ev), np.uint8))
        landmark_vertices[first_landmark:first_landmark + 5] = offset + iris
        offset += len(ev)
    upperness = np.where(np.isin(lip_loop, inner_upper), 1.0, np.where(np.isin(lip_loop, inner_lower), -1.0, 0.0))
    mv, msource, mdepth, mtri = _mouth_interior(lip_loop, pos, upperness)
    mouth_start = offset
    parts_pos.append(mv)
    # Mouth UVs: angle around the mouth -> angle in the disc, depth -> radius.
    angle = np.arctan2(*(mv[:, :2] - mv[:-1, :2].mean(0)).T[::-1])
    radius = maps.MOUTH_TEXTURE_RADIUS * (0.25 + 0.75 * mdepth)
    mouth_uv = np.array(maps.MOUTH_TEXTURE_CENTRE) + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
    parts_uv.append(mouth_uv)
    # Both windings: an opening jaw turns some walls away from the camera, and back faces
    # are culled (FaceRig.double_sided False); the bag is dark either way.
    parts_tri.append(np.vstack([mtri, mtri[:, ::-1]]) + offset)
    parts_mat.append(np.full(len(mv), 2, np.uint8))
    mouth_end = mouth_start + len(mv)
    # Teeth and tongue: the upper teeth ride the head, the lower ones and the tongue the jaw.
    tv, tuv, ttri, tpart = _teeth_and_tongue(pos[lip_loop])
    parts_pos.append(tv)
    parts_uv.append(tuv)
    parts_tri.append(ttri + mouth_end)
    parts_mat.append(np.full(len(tv), 3, np.uint8))
    # The head beyond the face (material 4): scalp, back of the head and neck grown from
    # the face's outer edge (its first ring shares the edge's positions), then the ears.
    head_start = mouth_end + len(tv)
    edge = max(loops, key=len)
    hv, hring, hcol, htri = _head_shell(pos[edge], pos[152])
    n_edge = len(edge)
    parts_pos.append(hv)
    parts_uv.append(np.stack([maps.HEAD_U[0] + (maps.HEAD_U[1] - maps.HEAD_U[0]) * hcol / n_edge,
                              maps.HEAD_V[0] + (maps.HEAD_V[1] - maps.HEAD_V[0]) * hring / HEAD_RINGS], 1))
    parts_tri.append(htri + head_start)
    parts_mat.append(np.full(len(hv), 4, np.uint8))
    ears_start = head_start + len(hv)
    ear_parts = []
    ear_y = 0.5 * (pos[[33, 263], 1].mean() + pos[2, 1])  # between eye and nose base levels
    ear_z = float(pos[edge, 2].min()) - 2.2
    for side, (u0, u1) in ((-1.0, maps.EAR_U["R"]), (1.0, maps.EAR_U["L"])):
        near = (np.abs(hv[:, 1] - ear_y) < 1.0) & (np.abs(hv[:, 2] - ear_z) < 1.0) & (hv[:, 0] * side > 0)
        x = float(np.abs(hv[near, 0]).max()) if near.any() else float(np.abs(pos[edge, 0]).max())
        ev, ecoord, efront, etri = _ear(np.array([side * (x + 0.35), ear_y, ear_z]), side, 6.0, 3.3)
        r_uv = np.where(efront, 0.5 * ecoord[:, 0], 1.0 - 0.5 * ecoord[:, 0]) * 0.5 * (maps.EAR_V[1] - maps.EAR_V[0])
        a = 2 * np.pi * ecoord[:, 1]
        c = np.array([0.5 * (u0 + u1), 0.5 * (maps.EAR_V[0] + maps.EAR_V[1])])
        ear_parts.append((ev, c + r_uv[:, None] * np.stack([np.cos(a), np.sin(a)], 1), etri))
    offset_e = ears_start
    for ev, euv, etri in ear_parts:
        parts_pos.append(ev)
        parts_uv.append(euv)
        parts_tri.append(etri + offset_e)
        parts_mat.append(np.full(len(ev), 4, np.uint8))
        offset_e += len(ev)
    n_ears = offset_e - ears_start

    all_pos = np.vstack(parts_pos)
    all_uv = np.vstack(parts_uv)
    all_tri = np.vstack(parts_tri).astype(np.int32)
    material = np.concatenate(parts_mat)
    V = len(all_pos)
    eye_vertex_side = np.full(V, -1, np.int8)
    eye_vertex_side[n_skin:n_skin + sum(map(len, eye_side))] = np.concatenate(eye_side)
    n_eye = mouth_start - n_skin

    # Skinning of the extra parts: eyes ride the head; the mouth interior copies the
    # contour vertex it hangs from (the cap takes the mean of the last ring).
    src = np.where(msource >= 0, msource, 0)
    m_joints, m_weights = joints[src].copy(), weights[src].copy()
    cap_dense = np.zeros((1, len(BONES)))
    last_ring = msource[-1 - len(lip_loop):-1]
    np.add.at(cap_dense[0], joints[last_ring].ravel(), weights[last_ring].ravel() / len(last_ring))
    cj, cw = _top4(cap_dense)
    m_joints[msource < 0], m_weights[msource < 0] = cj, cw
    jaw = [b.name for b in BONES].index("jaw")
    t_joints = np.zeros((len(tv), 4), np.int32)
    t_joints[tpart > 0, 0] = jaw
    # The head's first rings take the face edge's skinning, fading to the head bone.
    head_src = edge[hcol % n_edge]
    follow = (1.0 - features.smoothstep(hring / FACE_BLEND_RINGS))[:, None]
    h_dense = np.zeros((len(hv), len(BONES)))
    np.add.at(h_dense, (np.repeat(np.arange(len(hv)), 4), joints[head_src].ravel()),
              (follow * weights[head_src]).ravel())
    h_dense[:, 0] += 1.0 - follow[:, 0]
    h_joints, h_weights = _top4(h_dense)
    all_joints = np.vstack([joints, np.zeros((n_eye, 4), np.int32), m_joints, t_joints, h_joints,
                            np.zeros((n_ears, 4), np.int32)]).astype(np.int32)
    eye_w = np.zeros((n_eye + len(tv) + n_ears, 4), np.float32)
    eye_w[:, 0] = 1.0
    all_weights = np.vstack([weights, eye_w[:n_eye], m_weights, eye_w[n_eye:n_eye + len(tv)], h_weights,
                             eye_w[n_eye + len(tv):]]).astype(np.float32)
    # Vertices that share a position: the head's first ring and the face's edge, and each
    # ring's closing copy of its first vertex (UV seams without a shading seam).
    position_ids = np.arange(V, dtype=np.int32)
    head_ids = head_start + np.arange(len(hv))
    position_ids[head_ids[hcol == n_edge]] = head_ids[hcol == 0]
    position_ids[head_ids[hring == 0]] = edge[hcol[hring == 0] % n_edge]

    # Morphs over all vertices: eyes still; mouth interior follows its contour vertex,
    # less so deeper in.
    morph_names = list(skin_morphs)
    attenuation = (1.0 - 0.5 * mdepth)[:, None]
    rest_normals = _welded_normals(all_pos, all_tri, position_ids)
    mp = np.zeros((len(morph_names), V, 3))
    for i, name in enumerate(morph_names):
        d = skin_morphs[name]
        inner = d[src] * attenuation
        inner[msource < 0] = d[last_ring].mean(0) * attenuation[-1]
        mp[i, :n_skin] = d
        mp[i, mouth_start:mouth_end] = inner
    jaw_follow = _jaw_morphs(tv, (tpart > 0).astype(np.float64))
    for name, d in jaw_follow.items():
        if name in morph_names:
            mp[morph_names.index(name), mouth_end:head_start] = d
    mp[:, head_start:ears_start] = mp[:, head_src] * follow[None]
    morphed_normals = _welded_normals(all_pos[None] + mp, all_tri, position_ids)
    mn = morphed_normals - rest_normals[None]

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

    # Regions and zones from one UV layout.
    layout = features.feature_layout(mesh.uvs)
    region_weights = features.region_fields(all_uv[:, 0], all_uv[:, 1], layout) * (material == 0)
    zone_table = _zone_table(morph_names)

    tangents = mesh_ops.uv_tangents(all_pos, rest_normals, all_uv, all_tri)
    textures = maps.build_maps(mesh.uvs, all_uv, all_tri, material, iris_theta,
                               head_hair=_hair_grid(hv, n_edge),
                               head_shadow=_jaw_shadow_grid(hv, n_edge, float(pos[[61, 291], 1].mean())),
                               head_edge_uvs=all_uv[edge[np.arange(n_edge + 1) % n_edge]])

    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)
    return FaceRig(
        name="default" if variant == "default" else f"default_{variant}",
        vertices=f32(all_pos), normals=f32(rest_normals), uvs=f32(all_uv), tangents=f32(tangents),
        triangles=all_tri, position_ids=position_ids, material=material,
        landmark_vertices=landmark_vertices,
        bone_names=bone_names, bone_rest=f32(bone_rest),
        bone_parents=np.array([-1] + [0] * (len(BONES) - 1), np.int32),
        bone_landmarks=bone_landmarks, bone_groups=bone_groups,
        skin_joints=all_joints, skin_weights=all_weights,
        morph_names=morph_names, morph_positions=f32(mp), morph_normals=f32(mn),
        pose_names=pose_names, pose_bones=f32(pose_bones), pose_morph_weights=f32(pose_morph_weights),
        pose_maps=np.array([0, 1], np.int32), wrinkle_map_names=["stretch", "compress"],
        albedo=textures["albedo"], normal_map=textures["normal"],
        wrinkle_maps=np.stack([textures["stretch"], textures["compress"]]),
        zone_names=list(ZONE_NAMES), zone_masks=textures["zones"], zone_table=f32(zone_table),
        region_names=list(REGION_NAMES), region_weights=f32(region_weights),
        eye_centres=f32(eye_centres), eye_vertex_side=eye_vertex_side, double_sided=False,
    )


def _welded_normals(positions: np.ndarray, triangles: np.ndarray, position_ids: np.ndarray) -> np.ndarray:
    """Vertex normals (..., V, 3) computed over positions, not vertices: copies of one
    position (a UV seam) share one normal, so no shading seam shows."""
    return mesh_ops.vertex_normals(positions, position_ids[triangles])[..., position_ids, :]


def _head_grid(hv: np.ndarray, n_edge: int) -> np.ndarray:
    """(HEAD_RINGS + 1, n_edge + 1, 3) the head shell's vertices as a grid (the pole's row
    repeated)."""
    return np.concatenate([hv[:-1].reshape(HEAD_RINGS, n_edge + 1, 3), np.repeat(hv[-1:], n_edge + 1, 0)[None]])


def _jaw_shadow_grid(hv: np.ndarray, n_edge: int, mouth_y: float) -> np.ndarray:
    """(HEAD_RINGS + 1, n_edge + 1) how much darker the neck's skin is painted just under
    the jaw (the jaw's shadow: on people it draws the jaw line a tracker follows; on a
    uniformly lit neck the chin melts into it). 0 on the face's edge itself."""
    p = _head_grid(hv, n_edge)
    below = p[0, :, 1][None] - p[..., 1]  # cm under the jaw's edge, per column
    lower = features.smoothstep((mouth_y - p[0, :, 1]) / 2.0)[None]  # columns along the jaw
    along = np.vstack([np.zeros((1, n_edge + 1)), np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=-1), axis=0)])
    near = 1.0 - features.smoothstep((along - 3.0) / 2.0)  # the jaw's underside, not the nape
    return (0.45 * lower * near * features.smoothstep(below / 1.2)
            * (1.0 - features.smoothstep((below - 2.0) / 3.0))).astype(np.float32)


def _hair_grid(hv: np.ndarray, n_edge: int) -> np.ndarray:
    """(HEAD_RINGS + 1, n_edge + 1) hair coverage in [0, 1] at the head shell's vertices:
    above a hairline that runs from the forehead's edge over the ears to the nape, and
    at least a centimetre from the face's edge (skin meets skin there)."""
    p = _head_grid(hv, n_edge)
    step = np.linalg.norm(np.diff(p, axis=0), axis=-1)
    from_edge = np.vstack([np.zeros((1, n_edge + 1)), np.cumsum(step, axis=0)])
    z_front = float(p[0, :, 2].max())
    hairline = np.interp(p[..., 2] - z_front, [-19.0, -13.0, -8.5, -4.5], [-3.5, 0.5, 4.2, 7.5])
    return (features.smoothstep((from_edge - 0.1) / 0.7) * features.smoothstep((p[..., 1] - hairline) / 1.2)).astype(np.float32)


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

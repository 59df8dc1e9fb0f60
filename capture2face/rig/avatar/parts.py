"""Geometry of the default avatar's parts beyond the face's skin: the eyeballs, the mouth
interior, the teeth and the tongue, the head shell (scalp, back of the head and neck) and
the ears, and the head shell's hair and jaw-shadow coverage for its texture.

Each part is built in its own local vertex numbering; :mod:`capture2face.rig.avatar.layout`
places the parts after the skin's vertices.
"""

from __future__ import annotations

import numpy as np

from capture2face.rig import features, maps


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
    fan, the quads ring after ring, the last pole's fan; :func:`ear`)."""
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


IRIS_RADIUS_CM = 0.58


def eyeball(ring_pos: np.ndarray, side: str):
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

    def depth_at(c):
        return c + np.sqrt(np.maximum(radius**2 - reach**2, 0.0))

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


def mouth_interior(lip_loop: np.ndarray, pos: np.ndarray, upper: np.ndarray):
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


def teeth_and_tongue(ring: np.ndarray):
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

    def curve(x, dz):
        return np.stack([x * (half - 0.15), np.zeros_like(x), z_front - dz - 1.3 * x**2], 1)

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


def head_shell(edge: np.ndarray, chin: np.ndarray):
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


def ear(centre: np.ndarray, side: float, height: float, width: float):
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

    def depth(r):
        return 0.45 * np.exp(-((r - 0.88) / 0.1) ** 2) - 0.35 * np.exp(-((r - 0.35) / 0.2) ** 2)

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


def _head_grid(hv: np.ndarray, n_edge: int) -> np.ndarray:
    """(HEAD_RINGS + 1, n_edge + 1, 3) the head shell's vertices as a grid (the pole's row
    repeated)."""
    return np.concatenate([hv[:-1].reshape(HEAD_RINGS, n_edge + 1, 3), np.repeat(hv[-1:], n_edge + 1, 0)[None]])


def jaw_shadow_grid(hv: np.ndarray, n_edge: int, mouth_y: float) -> np.ndarray:
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


def hair_grid(hv: np.ndarray, n_edge: int) -> np.ndarray:
    """(HEAD_RINGS + 1, n_edge + 1) hair coverage in [0, 1] at the head shell's vertices:
    above a hairline that runs from the forehead's edge over the ears to the nape, and
    at least a centimetre from the face's edge (skin meets skin there)."""
    p = _head_grid(hv, n_edge)
    step = np.linalg.norm(np.diff(p, axis=0), axis=-1)
    from_edge = np.vstack([np.zeros((1, n_edge + 1)), np.cumsum(step, axis=0)])
    z_front = float(p[0, :, 2].max())
    hairline = np.interp(p[..., 2] - z_front, [-19.0, -13.0, -8.5, -4.5], [-3.5, 0.5, 4.2, 7.5])
    return (features.smoothstep((from_edge - 0.1) / 0.7)
            * features.smoothstep((p[..., 1] - hairline) / 1.2)).astype(np.float32)

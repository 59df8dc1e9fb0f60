"""A character's tracker landmarks found automatically: its face rendered from the front,
tracked with the clips' tracker, each landmark cast onto the skin's surface (a point on a
triangle, barycentric).

* **Steady**: each view is tracked as still images (MediaPipe's IMAGE mode: VIDEO mode's
  smoothing pulled the mouth-open view's lips towards the closed mouth before it), 25
  times, shifted by up to a pixel, and each landmark is the median: one image's landmarks
  move by tenths of a pixel with any change of its pixels, so the same face from another
  tool (quantized positions) would land a millimetre elsewhere.
* **Skin only**: the landmarks land on skin triangles (irises on the eyes), never on
  eyeballs, teeth, the mouth cavity, or see-through overlays in front of the face (lash and
  hair cards, glasses: ``FaceRig.overlay_vertices``).
* **At the depth the tracker sees**: MediaPipe gives each landmark a relative depth; fitted
  to the character's own (an affine map, over the landmarks that hit skin squarely), it
  rejects the surfaces a pixel's ray also meets far behind or before the face (the back of
  the head, the eye and mouth sockets behind an eyeball or the teeth). Among the rest, the
  triangle nearest the landmark in the image (a containing one, front-most).
* **Inner lips on their own lips**: at rest the mouth is closed and the upper and lower
  inner-lip landmarks meet at one line; they are cast in a second view with the mouth
  opened by the character's own ``jawOpen`` morph (0.5; 1.0 where the pair 13-14 then
  still fails the check below), and the triangle and barycentric weights they land on
  there are the same points of the rest mesh.
* **Lids on their own lids**: cast at rest (the eyes are open); where a pair then fails the
  load-time check (:func:`capture2face.measures.landmark_faults`: eyeBlink must close it
  by half), that eye's lids are cast again with the eyes opened by ``eyeWide``; where it
  still fails, that eye's upper-lid landmarks are moved onto the lid's margin, the skin its
  blink moves furthest under each (:func:`lids_on_margin`; Rocketbox's right eye: the
  tracker put 159 on the crease above the lid, 0.2 cm high and 0.4 cm in front, where the
  blink moves the skin 0.18 cm of the margin's 0.85). Kept only where the pair then passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.camera import framing_pose, project
from capture2face.errors import CaptureError
from capture2face.measures import landmark_faults
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.rig.arkit_names import arkit_weights
from capture2face.rig.deform import deform
from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.runtime.log import log
from capture2face.topology import (
    ARKIT_NAMES,
    IOD_PAIR,
    LID_LOWER_LEFT,
    LID_LOWER_RIGHT,
    LID_UPPER_LEFT,
    LID_UPPER_RIGHT,
    LIP_INNER_CORNERS,
    LIP_INNER_LOWER,
    LIP_INNER_UPPER,
    N_MESH,
)
from capture2face.tracking.landmarker import FaceLandmarker, LandmarkerOptions

# The front view's size in pixels.
RENDER_SIZE = 512
# MediaPipe's inner lip contour, upper (13 in the middle) and lower (14); the corners
# (78, 308) belong to both.
INNER_LIP_UPPER = LIP_INNER_UPPER
INNER_LIP_LOWER = LIP_INNER_LOWER
INNER_LIPS = LIP_INNER_CORNERS + INNER_LIP_UPPER + INNER_LIP_LOWER
# MediaPipe's eyelid contours (corners excluded), upper then lower: the subject's right
# eye, then the left.
EYELIDS_RIGHT = LID_UPPER_RIGHT + LID_LOWER_RIGHT
EYELIDS_LEFT = LID_UPPER_LEFT + LID_LOWER_LEFT
# Landmarks cast in views of their own, opened by the character's morphs (ARKit names):
# (morphs, {measure: its landmarks}, weights tried in turn, always, what they open). Always:
# the first weight's view is cast whatever the rest view gave; the next weights (or all, if
# not always) only for the measures whose pair still fails the check
# (:func:`capture2face.measures.landmark_faults`).
OPENED_VIEWS = (
    (("jawOpen",), {"mouth_open": INNER_LIPS}, (0.5, 1.0), True, "mouth opened by jawOpen (inner lips)"),
    (("eyeWideLeft", "eyeWideRight"), {"eye_right": EYELIDS_RIGHT, "eye_left": EYELIDS_LEFT}, (1.0,), False,
     "eyes opened by eyeWide (eyelids)"),
)
# The eyes' upper-lid contours (MediaPipe) by the measure of their opening, and the blink
# that closes them: the lids re-placed onto their margin (lids_on_margin).
UPPER_LIDS = {"eye_right": (LID_UPPER_RIGHT, "eyeBlinkRight"), "eye_left": (LID_UPPER_LEFT, "eyeBlinkLeft")}
# Shifts (px) of each tracked view: the landmarks are the median over them (_steady_landmarks).
JITTER_PX = tuple((dx, dy) for dx in (-1.0, -0.5, 0.0, 0.5, 1.0) for dy in (-1.0, -0.5, 0.0, 0.5, 1.0))
# Search radius (px) around a landmark for triangles to land on.
SEARCH_PX = 12.0
# A surface further than this (in inter-ocular distances) from the depth the tracker gives
# the landmark is not the one it sees.
DEPTH_TOL_IOD = 0.12
# Triangles this near a landmark in the image (px) are all under it: those further than
# BEHIND_TOL depth tolerances behind the front-most of them are hidden by it.
SAME_PX = 0.5
BEHIND_TOL = 0.1
SKIN_CODES = (0,)  # FaceRig.material: the face's skin (not the rest of the head, hair, lashes)
EYE_CODE = 1


def overlay_mask(rig: FaceRig) -> np.ndarray:
    """(V,) bool the rig's overlay vertices (hair and lash cards, beards, glasses); all False
    where it has none."""
    return np.zeros(rig.n_vertices, bool) if rig.overlay_vertices is None else np.asarray(rig.overlay_vertices)


def skin_vertices(rig: FaceRig) -> np.ndarray:
    """(V,) bool the face's skin (:data:`SKIN_CODES`), overlays left out: where landmarks go."""
    return np.isin(np.asarray(rig.material), SKIN_CODES) & ~overlay_mask(rig)


@dataclass
class SurfaceLandmarks:
    """Each tracker landmark's point on the character's surface (L landmarks).

    Attributes:
        faces: (L, 3) int32 vertex ids of its triangle (-1 where none).
        bary: (L, 3) float32 barycentric weights on it (0 where none).
        vertices: (L,) int32 the nearest of the three (-1 where none).
    """

    faces: np.ndarray
    bary: np.ndarray
    vertices: np.ndarray


@dataclass
class _View:
    """One tracked render: deformed vertices and normals (V, 3), pose (4, 4), the tracker's
    landmarks (L, 2) px and relative depths (L,) px."""

    vertices: np.ndarray
    normals: np.ndarray
    pose: np.ndarray
    landmarks_px: np.ndarray
    depth_px: np.ndarray


def with_surface_landmarks(rig: FaceRig) -> FaceRig:
    """``rig`` with ``landmark_faces``, ``landmark_bary`` and ``landmark_vertices`` from
    :func:`find_surface_landmarks`."""
    found = find_surface_landmarks(rig)
    return rig.replace(landmark_faces=found.faces, landmark_bary=found.bary, landmark_vertices=found.vertices)


def find_surface_landmarks(rig: FaceRig) -> SurfaceLandmarks:
    """Every MediaPipe landmark of the character's front view cast onto its skin (see the
    module docs); the landmarks of :data:`OPENED_VIEWS` from views with the character's own
    morphs opening them.

    Raises:
        CaptureError: the tracker finds no face in the render.
    """
    opts = RenderOptions(size=RENDER_SIZE, wrinkles="off", samples=4)
    # The views drawn and cast with the summed morph normals, as the landmarks were found
    # and judged before the renderer turned a user's normals by its shape (the same landmarks).
    rig = rig.replace(normals_from_shape=False)
    fov = opts.fov_y_degrees
    pose = framing_pose(rig, fov_y_degrees=fov)
    with Renderer(rig, opts) as renderer, \
            FaceLandmarker.create_from_options(LandmarkerOptions(num_faces=1, still_images=True)) as landmarker:
        rest = _tracked_view(renderer, landmarker, rig, pose)
        if rest is None:
            raise CaptureError(f"character '{rig.name}': the tracker finds no face in its front view")
        out = _cast_view(rig, rest, fov)
        for names, groups, weights, always, what in OPENED_VIEWS:
            opens = pose_weights(rig, names)  # the ARKit morphs, else the visemes / presets they drive
            for k, weight in enumerate(weights if opens.any() else ()):
                todo = groups
                if k or not always:  # a fallback: only for the measures the landmarks so far fail
                    faults = landmark_faults(rig.replace(landmark_faces=out.faces, landmark_bary=out.bary,
                                                         landmark_vertices=out.vertices))
                    todo = {m: rows for m, rows in groups.items() if m in faults}
                if todo:
                    _recast(rig, out, _tracked_view(renderer, landmarker, rig, pose, weight * opens),
                            fov, [r for rows in todo.values() for r in rows], what)
    return lids_on_margin(rig, out)


def lids_on_margin(rig: FaceRig, out: SurfaceLandmarks) -> SurfaceLandmarks:
    """``out`` (in place) with the upper-lid landmarks of each eye whose pair fails the
    load-time check (:func:`capture2face.measures.landmark_faults`) moved onto the lid's
    margin: each onto the skin vertex its blink moves furthest within its own strip of the
    lid (half the spacing of the contour's landmarks either side of it, an eye's width
    above and below), the front-most of equally far ones. The margin travels furthest in a
    blink and is the lid the eye's measures mean (where the other eye's landmarks sit); a
    landmark on the crease above it (a fold the front view sees over the lid) hardly moves.
    Kept only where the pair then passes the check; else that eye's landmarks stay as they
    were."""
    def placed_on(lms: SurfaceLandmarks) -> FaceRig:
        return rig.replace(landmark_faces=lms.faces, landmark_bary=lms.bary, landmark_vertices=lms.vertices)

    faults = landmark_faults(placed_on(out))
    verts = np.asarray(rig.vertices, np.float64)
    skin = skin_vertices(rig)
    for measure, (rows, blink) in UPPER_LIDS.items():
        rows = np.array(rows)
        placed = rows[out.vertices[rows] >= 0]
        if measure not in faults or len(placed) < 2:
            continue
        travel = np.linalg.norm(np.einsum("m,mvc->vc", pose_weights(rig, [blink]), rig.morph_positions,
                                          dtype=np.float64), axis=1)
        travel = np.where(skin, travel, 0.0)
        at = landmark_points(placed_on(out), verts, placed)  # (K, 3) where they are now
        width = float(np.ptp(at[:, 0]))
        half = 0.5 * width / (len(placed) - 1)
        strip = (np.abs(verts[:, 0] - at[:, None, 0]) <= half) & (np.abs(verts[:, 1] - at[:, None, 1]) <= width)
        score = np.where(strip & (travel > 0), travel + 1e-6 * verts[:, 2], -np.inf)  # (K, V)
        best = np.argmax(score, axis=1)
        ok = np.isfinite(score[np.arange(len(placed)), best])
        moved = SurfaceLandmarks(out.faces.copy(), out.bary.copy(), out.vertices.copy())
        moved.faces[placed[ok]] = best[ok, None]
        moved.bary[placed[ok]] = (1.0, 0.0, 0.0)
        moved.vertices[placed[ok]] = best[ok]
        if measure in landmark_faults(placed_on(moved)):
            continue
        log.info("character '%s': its %s upper-lid landmarks moved onto the lid's margin (the front view put "
                 "them where %s hardly moves)", rig.name, measure.removeprefix("eye_"), blink)
        out.faces[placed], out.bary[placed], out.vertices[placed] = (moved.faces[placed], moved.bary[placed],
                                                                     moved.vertices[placed])
    return out


def _recast(rig: FaceRig, out: SurfaceLandmarks, view, fov_y_degrees: float, rows: list, what: str) -> None:
    """``out``'s landmarks ``rows`` cast again in ``view`` (in place); a warning where the
    tracker found no face in it."""
    if view is None:
        log.warning("character '%s': the tracker finds no face with its %s; they are placed at rest", rig.name, what)
        return
    cast = _cast_view(rig, view, fov_y_degrees)
    rows = np.array(rows)
    rows = rows[cast.vertices[rows] >= 0]
    out.faces[rows], out.bary[rows], out.vertices[rows] = cast.faces[rows], cast.bary[rows], cast.vertices[rows]


def pose_weights(rig: FaceRig, names, weight: float = 1.0) -> np.ndarray:
    """(M,) float32 the rig's morph weights for the ARKit curves ``names`` at ``weight`` (the
    rest 0): its ARKit morphs of those names, or, on a character without ARKit names, the
    visemes / presets / Rocketbox morphs the curves drive
    (:func:`~capture2face.rig.arkit_names.arkit_weights`)."""
    curves = np.zeros((1, len(ARKIT_NAMES)), np.float32)
    curves[0, [ARKIT_NAMES.index(n) for n in names]] = weight
    return arkit_weights(ARKIT_NAMES, curves, rig.morph_names)[0]


def _tracked_view(renderer: Renderer, landmarker, rig: FaceRig, pose: np.ndarray, weights=None):
    """The :class:`_View` of the rig with morph ``weights`` (M,) (None: all 0), or None
    where the tracker finds no face."""
    weights = np.zeros(rig.n_morphs, np.float32) if weights is None else np.asarray(weights, np.float32)
    found = _steady_landmarks(landmarker, renderer.render(FrameState(rig.bone_rest.copy(), weights, pose)))
    if found is None:
        return None
    verts, normals = deform(rig, rig.bone_rest, weights)
    return _View(np.asarray(verts, np.float64), np.asarray(normals, np.float64), pose, *found)


def _steady_landmarks(landmarker, image: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(L, 2) landmarks (px) and (L,) relative depths of ``image``, each the median over the
    image shifted by :data:`JITTER_PX` (shifts undone), or None where the tracker finds no
    face in most of them (``landmarker``: still-image mode)."""
    import cv2

    px, depth = [], []
    for dx, dy in JITTER_PX:
        shift = np.float32([[1, 0, dx], [0, 1, dy]])
        moved = image if dx == dy == 0 else cv2.warpAffine(image, shift, image.shape[1::-1],
                                                           flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        obs = landmarker.detect(moved, 0.0)
        if obs is None:
            continue
        px.append(obs.landmarks_px.astype(np.float64) - (dx, dy))
        depth.append(obs.depth.astype(np.float64))
    if len(px) * 2 <= len(JITTER_PX):  # a face in fewer than half of them: none
        return None
    return np.median(px, axis=0), np.median(depth, axis=0)


def _cast_view(rig: FaceRig, view: _View, fov_y_degrees: float) -> SurfaceLandmarks:
    """Every landmark of ``view`` cast onto the allowed triangles of its deformed mesh:
    the face's 468 onto skin, the irises onto the eyes."""
    L = len(view.landmarks_px)
    px = project(view.vertices, view.pose, fov_y_degrees, RENDER_SIZE)  # (V, 2)
    cam = view.vertices @ view.pose[:3, :3].T + view.pose[:3, 3]
    depth = -cam[:, 2]
    tris = np.asarray(rig.triangles, np.int64)
    # Facing the camera (by the vertex normals: a file's winding may be either way): the back
    # of a head projects onto the face too.
    normals = view.normals[tris].sum(1) @ view.pose[:3, :3].T  # (T, 3) camera space
    facing = np.einsum("tc,tc->t", normals, -cam[tris].mean(1)) > 0
    facing &= np.isfinite(px[tris]).all((1, 2))
    mat = np.asarray(rig.material)
    clean = facing & ~overlay_mask(rig)[tris].any(1)
    skin = clean & np.isin(mat[tris], SKIN_CODES).all(1)
    eyes = clean & (mat[tris] == EYE_CODE).all(1)
    faces = np.full((L, 3), -1, np.int32)
    bary = np.zeros((L, 3), np.float32)
    rows_face, rows_iris = np.arange(min(L, N_MESH)), np.arange(N_MESH, L)
    hits = _candidates(px, depth, tris[skin], view.landmarks_px[rows_face])
    expect, tol = _expected_depth(rig, view, hits, rows_face, fov_y_degrees)
    for rows, h in ((rows_face, hits), (rows_iris, _candidates(px, depth, tris[eyes], view.landmarks_px[rows_iris]))):
        face_rows = expect is not None and len(rows) and rows[0] < N_MESH
        pick = _choose(h, len(rows), expect[rows] if face_rows else None, tol)
        # None at the tracker's depth (a landmark on the silhouette): the nearest facing skin.
        pick = np.where(pick >= 0, pick, _choose(h, len(rows), None, tol))
        ok = pick >= 0
        faces[rows[ok]] = h.tris[pick[ok]]
        bary[rows[ok]] = h.bary[pick[ok]]
    lmv = np.where((faces >= 0).all(1), faces[np.arange(L), np.argmax(bary, 1)], -1).astype(np.int32)
    return SurfaceLandmarks(faces, bary, lmv)


@dataclass
class _Hits:
    """Landmark x triangle pairs near each other in the image (N of them): the landmark's
    row (N,), the triangle's vertices (N, 3), the 2D distance (px) from the landmark to the
    triangle (0 inside), the barycentric weights (N, 3) of the triangle's point nearest it
    (perspective-correct: a point of the 3D triangle) and that point's depth (N,) cm."""

    row: np.ndarray
    tris: np.ndarray
    dist: np.ndarray
    bary: np.ndarray
    depth: np.ndarray


def _candidates(px: np.ndarray, depth: np.ndarray, tris: np.ndarray, points: np.ndarray) -> _Hits:
    """The triangles (T, 3) whose image box comes within :data:`SEARCH_PX` of each point
    (K, 2), with the point of each nearest the landmark."""
    corners = px[tris]  # (T, 3, 2)
    lo, hi = corners.min(1) - SEARCH_PX, corners.max(1) + SEARCH_PX
    if len(points):  # only triangles near the landmarks at all: a whole body projects mostly elsewhere
        box = ((lo <= points.max(0)) & (hi >= points.min(0))).all(1)
        tris, corners, lo, hi = tris[box], corners[box], lo[box], hi[box]
    rows, ts = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for s in range(0, len(points), 64):  # (64, T) at a time: memory stays small
        chunk = points[s:s + 64, None]
        r, t = np.nonzero(((chunk >= lo[None]) & (chunk <= hi[None])).all(-1))
        rows.append(r + s)
        ts.append(t)
    row, t = np.concatenate(rows), np.concatenate(ts)
    a, b, c = (corners[t, i] for i in range(3))
    p = points[row]
    q = _closest_on_triangle(p, a, b, c)
    l2 = _bary2d(q, a, b, c)
    z = depth[tris[t]]  # (N, 3)
    inv = l2 / np.maximum(z, 1e-6)
    b3 = inv / np.maximum(inv.sum(1, keepdims=True), 1e-12)
    return _Hits(row, tris[t].astype(np.int32), np.linalg.norm(p - q, axis=1), b3.astype(np.float32),
                 1.0 / np.maximum(inv.sum(1), 1e-12))


def _bary2d(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N, 3) barycentric weights of 2D points (N, 2) in triangles a, b, c (N, 2) each."""
    v0, v1, v2 = b - a, c - a, p - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    den = np.where(np.abs(den) < 1e-12, 1e-12, den)
    l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.clip(np.stack([1.0 - l1 - l2, l1, l2], 1), 0.0, 1.0)


def _closest_on_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N, 2) the point of each 2D triangle nearest p: p itself inside, else the nearest
    point of its edges."""
    def on_edge(u, v):
        d = v - u
        s = np.clip(np.einsum("nc,nc->n", p - u, d) / np.maximum(np.einsum("nc,nc->n", d, d), 1e-12), 0, 1)
        return u + s[:, None] * d

    edges = np.stack([on_edge(a, b), on_edge(b, c), on_edge(c, a)], 1)  # (N, 3, 2)
    best = edges[np.arange(len(p)), np.argmin(np.linalg.norm(edges - p[:, None], axis=2), 1)]
    cross = [(v[:, 0] - u[:, 0]) * (p[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (p[:, 0] - u[:, 0])
             for u, v in ((a, b), (b, c), (c, a))]
    inside = (np.stack(cross, 1) >= 0).all(1) | (np.stack(cross, 1) <= 0).all(1)
    return np.where(inside[:, None], p, best)


def _expected_depth(rig: FaceRig, view: _View, hits: _Hits, rows: np.ndarray,
                    fov_y_degrees: float) -> tuple[np.ndarray | None, float]:
    """(L,) the depth (cm) the tracker sees each landmark at, fitted affinely to the front-most
    skin under the landmarks that lie inside a triangle, and the tolerance (cm) about it;
    (None, 0) where no landmark lies inside one (nothing to fit: the nearest skin is taken)."""
    inside = hits.dist <= 0.0
    front = np.full(len(rows), np.inf)
    np.minimum.at(front, hits.row[inside], hits.depth[inside])
    ok = np.isfinite(front)
    if not ok.any():  # the median of no depth would be NaN (and a NumPy RuntimeWarning)
        return None, 0.0
    src = view.depth_px[rows]
    lms = np.flatnonzero(ok)
    fit = np.array([0.0, float(np.median(front[ok]))])
    for _ in range(3):  # least squares, then without the outliers (a ray through an eye's socket)
        if len(lms) < 8:
            break
        fit = np.polyfit(src[lms], front[lms], 1)
        resid = np.abs(np.polyval(fit, src[ok]) - front[ok])
        lms = np.flatnonzero(ok)[resid <= max(2.5 * np.median(resid), 1e-6)]
    iod_px = float(np.linalg.norm(view.landmarks_px[IOD_PAIR[0]] - view.landmarks_px[IOD_PAIR[1]]))
    cm_per_px = 2.0 * np.tan(np.radians(fov_y_degrees) / 2.0) * float(np.median(front[ok])) / RENDER_SIZE
    return np.polyval(fit, view.depth_px), DEPTH_TOL_IOD * iod_px * cm_per_px


def _choose(h: _Hits, n_rows: int, expect: np.ndarray | None, tol: float) -> np.ndarray:
    """(n_rows,) index into ``h`` of each landmark's triangle (-1: none): among those at the
    expected depth (within ``tol``), the nearest in the image, where those within
    :data:`SAME_PX` of the landmark but behind the front-most of them count as
    :data:`SAME_PX` further (the surface the camera sees there: on a silhouette, such as a
    nose wing's edge, the wing, not the cheek behind it); the front-most of equally near ones."""
    ok = np.ones(len(h.row), bool) if expect is None else np.abs(h.depth - expect[h.row]) <= tol
    near = ok & (h.dist <= SAME_PX)
    front = np.full(n_rows, np.inf)
    np.minimum.at(front, h.row[near], h.depth[near])
    behind = near & (h.depth > front[h.row] + BEHIND_TOL * tol)
    score = np.where(ok, h.dist + np.where(behind, SAME_PX, 0.0) + 1e-3 * (h.depth - h.depth.min(initial=0.0)),
                     np.inf)
    order = np.lexsort((score, h.row))
    first = np.ones(len(order), bool)
    first[1:] = h.row[order][1:] != h.row[order][:-1]
    out = np.full(n_rows, -1, np.int64)
    pick = order[first]
    good = np.isfinite(score[pick])
    out[h.row[pick[good]]] = pick[good]
    return out


def cast_front(rig: FaceRig, points: np.ndarray) -> SurfaceLandmarks:
    """Landmark points (L, 2), the head's x and y (cm; L = 478 rows, the face's 468 then the
    irises), each cast straight along the head's forward axis (+z) onto the front-most skin
    facing it (irises onto the eyes): a view from far in front, for landmarks placed without
    the tracker (:mod:`capture2face.character.morph_landmarks`)."""
    verts = np.asarray(rig.vertices, np.float64)
    size = max(rig.face_size(), 1e-6)
    px = verts[:, :2] * (RENDER_SIZE / size)  # image-like units: the search radii are in px
    # Distance behind a far plane in front: the front-most is the least; far, so the
    # barycentric weights' perspective correction is nil.
    depth = verts[:, 2].max() - verts[:, 2] + 1e3
    tris = np.asarray(rig.triangles, np.int64)
    facing = np.asarray(rig.normals, np.float64)[tris].sum(1)[:, 2] > 0
    mat = np.asarray(rig.material)
    clean = facing & ~overlay_mask(rig)[tris].any(1)
    L = len(points)
    faces = np.full((L, 3), -1, np.int32)
    bary = np.zeros((L, 3), np.float32)
    target = np.asarray(points, np.float64) * (RENDER_SIZE / size)
    for rows, keep in ((np.arange(min(L, N_MESH)), clean & np.isin(mat[tris], SKIN_CODES).all(1)),
                       (np.arange(N_MESH, L), clean & (mat[tris] == EYE_CODE).all(1))):
        hits = _candidates(px, depth, tris[keep], target[rows])
        pick = _choose(hits, len(rows), None, 1.0)
        ok = pick >= 0
        faces[rows[ok]] = hits.tris[pick[ok]]
        bary[rows[ok]] = hits.bary[pick[ok]]
    lmv = np.where((faces >= 0).all(1), faces[np.arange(L), np.argmax(bary, 1)], -1).astype(np.int32)
    return SurfaceLandmarks(faces, bary, lmv)

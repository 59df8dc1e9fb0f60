"""A character's tracker landmarks found from what its own morphs move, for faces the tracker
cannot read (anime, stylised, low-poly heads).

1. **Features from the morphs** (the ARKit morphs, else the visemes / VRM presets / Rocketbox
   morphs the same ARKit curves drive, :func:`~capture2face.character.landmarks.pose_weights`):
   each eye's upper lid is the skin ``eyeBlink`` moves most, its lower lid where that lid
   closes to, its corners the ends of what the blink moves; the mouth's lip line is the top
   of what ``jawOpen`` moves most, its corners what a smile moves most sideways among the
   skin the jaw moves too (a VRM's ``Joy`` is a whole-face feeling), else the ends of what
   the jaw moves along the lip line.
2. **MediaPipe's canonical face fitted to them**: an affine map of the head's x-y plane
   through both eye centres and the mouth's, corrected near each eye and the mouth by the
   found feature's own width and height (an anime eye is large, its mouth small), smoothly.
3. **Cast onto the skin** straight from the front (:func:`~.landmarks.cast_front`), the
   inner lips and lids then moved onto the vertices their morphs part: the upper inner lip
   onto skin about the lip line that the jaw does not lower (Godette's ``A`` parts its upper
   lip upwards and sideways: "still" skin was its nose), the lower onto what it moves, the
   mouth's corners onto the ends of what the jaw moves; the upper lid onto what the blink
   moves, the lower onto what it leaves.
"""

from __future__ import annotations

import numpy as np

from capture2face.character.landmarks import SurfaceLandmarks, cast_front, pose_weights
from capture2face.errors import CaptureError
from capture2face.rig.canonical import load_canonical_mesh
from capture2face.rig.face_rig import FaceRig
from capture2face.topology import (
    EYE_LEFT,
    EYE_RIGHT,
    IRIS_LEFT,
    IRIS_RIGHT,
    LID_LOWER_LEFT,
    LID_LOWER_RIGHT,
    LID_UPPER_LEFT,
    LID_UPPER_RIGHT,
    LIP_INNER_LOWER,
    LIP_INNER_UPPER,
    LIPS_OUTER,
    N_LANDMARKS,
    N_MESH,
)

MOVED = 0.5  # share of a morph's largest travel above which a vertex is what it moves
STILL = 0.2  # ... and below which it is what the morph leaves
SIDES = (("Right", EYE_RIGHT, LID_UPPER_RIGHT, LID_LOWER_RIGHT, IRIS_RIGHT, (33, 133), (159, 145)),
         ("Left", EYE_LEFT, LID_UPPER_LEFT, LID_LOWER_LEFT, IRIS_LEFT, (263, 362), (386, 374)))
CORNERS = ((61, 78), (291, 308))  # the mouth's right and left corners, outer and inner
MOUTH = tuple(sorted(set(LIPS_OUTER) | set(LIP_INNER_UPPER) | set(LIP_INNER_LOWER) | {78, 308}))


def morph_landmarks(rig: FaceRig) -> SurfaceLandmarks:
    """Every MediaPipe landmark placed on the character from its morphs (see the module docs).

    Raises:
        CaptureError: it has no morph that blinks an eye or opens the mouth.
    """
    verts = np.asarray(rig.vertices, np.float64)
    skin = (np.asarray(rig.material) == 0) & (np.asarray(rig.normals)[:, 2] > 0.2)
    if rig.overlay_vertices is not None:
        skin &= ~np.asarray(rig.overlay_vertices)
    eyes = [_eye(rig, verts, skin, side) for side, *_ in SIDES]
    mouth = _mouth(rig, verts, skin, eyes)
    canon = load_canonical_mesh().vertices.astype(np.float64)[:, :2]
    points = np.zeros((N_LANDMARKS, 2))
    points[:N_MESH] = _fit(canon, eyes, mouth)
    for e, (_, _, _, _, iris, _, _) in zip(eyes, SIDES):
        r = 0.2 * e["width"]
        points[list(iris)] = e["centre"] + np.array([[0, 0], [-r, 0], [0, r], [r, 0], [0, -r]])
    out = cast_front(rig, points)
    for e, (_, _, upper, lower, _, _, _) in zip(eyes, SIDES):
        _snap(out, verts, points, upper, skin & e["moved"])
        _snap(out, verts, points, lower, skin & e["still"])
    _snap(out, verts, points, LIP_INNER_UPPER, skin & mouth["still"])
    _snap(out, verts, points, LIP_INNER_LOWER, skin & mouth["moved"])
    for rows, corner in zip(CORNERS, mouth["corners"]):  # the mouth's ends (x < 0: its right)
        if corner >= 0:
            _snap(out, verts, points, rows, np.arange(len(verts)) == corner)
    return out


def _travel(rig: FaceRig, names) -> np.ndarray:
    """(V, 3) how far each vertex moves under the ARKit curves ``names`` at 1."""
    w = pose_weights(rig, names)
    return np.einsum("m,mvc->vc", w, rig.morph_positions, dtype=np.float64)


def _eye(rig: FaceRig, verts: np.ndarray, skin: np.ndarray, side: str) -> dict:
    """One eye's centre (2,), width, height and the skin its blink moves / leaves."""
    d = _travel(rig, [f"eyeBlink{side}"])
    length = np.where(skin, np.linalg.norm(d, axis=1), 0.0)
    if length.max() <= 0:
        raise CaptureError(f"character '{rig.name}': no morph closes its {side.lower()} eye")
    moved = length >= MOVED * length.max()
    lid = int(np.argmax(length))  # the lid's edge travels furthest
    top, bottom = verts[lid, 1], verts[lid, 1] + d[lid, 1]
    band = (length >= STILL * length.max()) & (verts[:, 1] <= top + 0.25 * (top - bottom))
    xs = verts[band | moved, 0]
    centre = np.array([(xs.min() + xs.max()) / 2, (top + bottom) / 2])
    near = np.abs(verts[:, 0] - centre[0]) <= (xs.max() - xs.min())
    return {"centre": centre, "width": float(xs.max() - xs.min()), "height": float(top - bottom),
            "moved": moved, "still": (length < STILL * length.max()) & near}


def _mouth(rig: FaceRig, verts: np.ndarray, skin: np.ndarray, eyes: list[dict]) -> dict:
    """The mouth's centre (2,), width, opening and the skin the jaw moves / leaves (below
    the eyes, within an eye distance of their middle: a body's skin is all skin)."""
    mid_x = (eyes[0]["centre"][0] + eyes[1]["centre"][0]) / 2
    iod = abs(eyes[1]["centre"][0] - eyes[0]["centre"][0])
    eye_y = min(e["centre"][1] for e in eyes)
    skin = skin & (np.abs(verts[:, 0] - mid_x) <= iod) & (verts[:, 1] < eye_y) & (verts[:, 1] > eye_y - 2.5 * iod)
    d = _travel(rig, ["jawOpen"])
    length = np.where(skin, np.linalg.norm(d, axis=1), 0.0)
    if length.max() <= 0:
        raise CaptureError(f"character '{rig.name}': no morph opens its mouth")
    moved = length >= MOVED * length.max()
    width_all = 2 * iod
    central = moved & (np.abs(verts[:, 0] - mid_x) <= 0.05 * width_all)
    lip = np.flatnonzero(central if central.any() else moved)
    lip = lip[np.argmax(verts[lip, 1])]  # the lower lip's top: the highest point the jaw moves
    line = verts[lip, 1]
    half_eyes = 0.5 * width_all
    # The mouth's ends: what the jaw moves along the lip line. A smile's ends where the
    # smile moves skin the jaw moves too (an ARKit smile pulls the corners; a VRM's Joy
    # and Fun are whole-face feelings, whose sideways travel lies on the cheeks).
    jaw_ends = np.flatnonzero((length >= STILL * length.max()) & (np.abs(verts[:, 1] - line) <= 0.15 * half_eyes))
    smile = _travel(rig, ["mouthSmileLeft", "mouthSmileRight"])
    side = np.where(skin & (length >= STILL * length.max()), np.abs(smile[:, 0]), 0.0)
    ends = np.array([], np.int64)
    if side.max() > 0:
        ends = np.flatnonzero(skin & (side >= 0.8 * side.max()) & (np.abs(verts[:, 1] - line) <= 0.15 * half_eyes))
    if len(ends) < 2:
        ends = jaw_ends
    width = 2 * float(np.abs(verts[ends, 0] - mid_x).max()) if len(ends) else 0.25 * width_all
    opening = float(-d[lip, 1])
    near = np.abs(verts[:, 0] - mid_x) <= width
    inside = np.abs(verts[:, 0] - mid_x) <= 0.55 * width
    # The upper lip: skin about the lip line the jaw does not lower (it may part it upwards
    # or sideways: Godette's A moves its upper lip's ends by half the lower lip's drop).
    upper = (-d[:, 1] < STILL * length.max()) & inside & (verts[:, 1] >= line) & (verts[:, 1] <= line + 0.5 * width)
    sides = [jaw_ends[verts[jaw_ends, 0] < mid_x], jaw_ends[verts[jaw_ends, 0] >= mid_x]]
    corners = [int(s[np.argmax(np.abs(verts[s, 0] - mid_x))]) if len(s) else -1 for s in sides]
    return {"centre": np.array([mid_x, line]), "width": width, "height": max(opening, 1e-3),
            "moved": moved, "still": upper if upper.any() else
            (length < STILL * length.max()) & near & (verts[:, 1] >= line - 0.5 * opening), "corners": corners}


def _fit(canon: np.ndarray, eyes: list[dict], mouth: dict) -> np.ndarray:
    """(468, 2) the canonical face's x-y in the head: affine through the eye and mouth
    centres, each feature's neighbourhood scaled to its own width and height."""
    c_eyes = [canon[list(corners)].mean(0) * [1, 0] + [0, canon[list(lids)][:, 1].mean()]
              for _, _, _, _, _, corners, lids in SIDES]
    c_mouth = np.array([canon[[61, 291], 0].mean(), canon[[13, 14], 1].mean()])
    src = np.array([*c_eyes, c_mouth])
    dst = np.array([eyes[0]["centre"], eyes[1]["centre"], mouth["centre"]])
    affine = np.linalg.solve(np.c_[src, np.ones(3)], dst)  # (3, 2): [x y 1] @ affine
    glob = np.c_[canon, np.ones(len(canon))] @ affine
    boxes = []
    for e, (_, _, _, _, _, corners, lids) in zip(eyes, SIDES):
        cw = abs(canon[corners[0], 0] - canon[corners[1], 0])
        ch = abs(canon[lids[0], 1] - canon[lids[1], 1])
        boxes.append((src[len(boxes)], cw, ch, e["centre"], e["width"], e["height"]))
    cw = abs(canon[61, 0] - canon[291, 0])
    boxes.append((c_mouth, cw, 0.5 * cw, mouth["centre"], mouth["width"], 0.5 * mouth["width"]))
    out, total = glob.copy(), np.zeros(len(canon))
    for c, cw, ch, centre, w, h in boxes:
        local = centre + (canon - c) * [w / cw, max(h, 0.1 * w) / ch]
        weight = np.exp(-(np.linalg.norm((canon - c) / [cw, cw], axis=1) / 0.75) ** 2)
        out += weight[:, None] * (local - glob)
        total += weight
    return np.where(total[:, None] > 1, glob + (out - glob) / np.maximum(total, 1)[:, None], out)


def _snap(out: SurfaceLandmarks, verts: np.ndarray, points: np.ndarray, rows, allowed: np.ndarray) -> None:
    """``out``'s landmarks ``rows`` moved (in place) onto the allowed vertex nearest each
    one's point in the head's x-y plane (the front-most of equally near ones)."""
    ids = np.flatnonzero(allowed)
    if not len(ids):
        return
    rows = np.asarray(rows)
    dist = np.linalg.norm(verts[ids, None, :2] - points[None, rows], axis=2)  # (n, R)
    dist -= 1e-3 * verts[ids, 2:3]
    best = ids[np.argmin(dist, axis=0)]
    out.faces[rows] = best[:, None]
    out.bary[rows] = [1.0, 0.0, 0.0]
    out.vertices[rows] = best

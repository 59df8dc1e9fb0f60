"""Gaze from the tracked irises: per-eye yaw and pitch in head coordinates (degrees).

MediaPipe's landmarks 468-472 (the subject's right iris: centre, then four rim points)
and 473-477 (left) come with the face in head coordinates (head motion removed). An eye
turns about its centre, so the iris moves across the face by ``r sin(angle)``, r the
distance from the eye's centre of rotation to the iris. Per frame and eye:

* ``d`` = the mean of the five iris landmarks minus the midpoint of the eye's corners
  (33/133, 263/362): measured against the eye's own corners, so what head-pose
  stabilization leaves of head motion cancels;
* straight ahead is ``d`` at the actor's rest (the eyes' rest frames, where the eyes are
  most relaxed and look straight ahead, :mod:`capture2face.tracking.rest`), so the
  actor's anatomy (where the iris sits between the corners) needs no model;
* ``pitch = asin(-dy / r)`` (> 0 down), ``yaw = asin(dx / (r cos pitch))`` (> 0 towards
  the subject's left), ``dx, dy`` relative to straight ahead, r = ``radius_iod`` times the
  inter-ocular distance (outer corners) at rest;
* the eyes' pitch is their mean (vertical vergence is nil in healthy eyes, and the mean
  halves the landmarks' noise), yaw stays per eye (horizontal vergence is real);
* while a lid is nearly closed (opening 159-145 / 386-374 below ``CLOSED_FRACTION`` of
  its rest opening) its iris landmarks follow the lid, not the eye: the other eye's
  angles are used when it is open, else the gaze is interpolated over the blink.

Signs and units are those of ``Animation.eye_rotation`` and Live Link Face.
"""

from __future__ import annotations

import numpy as np

from capture2face.io.framestore import take_points
from capture2face.rig.face_rig import landmark_points
from capture2face.topology import (
    EYE_CORNERS_LEFT,
    EYE_CORNERS_RIGHT,
    IOD_PAIR,  # the outer eye corners: the face's size
    IRIS_LEFT,
    IRIS_RIGHT,
    LIDS_LEFT,
    LIDS_RIGHT,
)

# Right eye (the subject's right, -x) first, as everywhere: (iris landmarks, corners, lids).
EYES = (
    (np.array(IRIS_RIGHT), EYE_CORNERS_RIGHT, LIDS_RIGHT),
    (np.array(IRIS_LEFT), EYE_CORNERS_LEFT, LIDS_LEFT),
)
# Distance from the eye's centre of rotation to the tracked iris centre, in inter-ocular
# distances (outer corners): a human eye of radius 12 mm whose iris plane lies ~11 mm in
# front of its centre, on a face with ~9 cm between the outer eye corners.
HUMAN_RADIUS_IOD = 0.12
CLOSED_FRACTION = 0.45  # a lid opening below this fraction of the rest one: iris unreliable
MAX_DEG = 45.0  # the eye's mechanical range: estimates beyond it are clipped


def iris_offsets(landmarks_head, chunk: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame: iris offsets from the eye-corner midpoints (F, 2, 3) cm, lid openings
    (F, 2) cm and the inter-ocular distance (F,) cm.

    Args:
        landmarks_head: (F, 478, 3) head-coordinate landmarks (an array or a disk-backed
            FrameArray: read a block of frames at a time).
    """
    ids = sorted({int(i) for iris, c, lids in EYES for i in (*iris, *c, *lids)} | set(IOD_PAIR))
    col = {i: k for k, i in enumerate(ids)}
    pts = take_points(landmarks_head, ids, chunk)  # ~20 landmarks
    n = len(pts)
    offsets = np.empty((n, 2, 3))
    opening = np.empty((n, 2))
    for e, (iris, (a, b), (up, lo)) in enumerate(EYES):
        centre = pts[:, [col[int(i)] for i in iris]].mean(1)
        offsets[:, e] = centre - 0.5 * (pts[:, col[a]] + pts[:, col[b]])
        opening[:, e] = np.linalg.norm(pts[:, col[up]] - pts[:, col[lo]], axis=-1)
    iod = np.linalg.norm(pts[:, col[IOD_PAIR[0]]] - pts[:, col[IOD_PAIR[1]]], axis=-1)
    return offsets, opening, iod


def _fill_closed(values: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """(F,) values with the ``bad`` frames linearly interpolated from the good ones."""
    good = np.flatnonzero(~bad)
    if len(good) == 0 or len(good) == len(values):
        return values
    return np.interp(np.arange(len(values)), good, values[good])


def eye_rotation(landmarks_head, rest: np.ndarray, radius_iod: float = HUMAN_RADIUS_IOD) -> np.ndarray:
    """(F, 2, 2) float32 yaw, pitch in degrees per eye (right, left) from the tracked irises.

    Args:
        landmarks_head: (F, 478, 3) head-coordinate landmarks (cm).
        rest: (478, 3) the landmarks at rest, eyes looking straight ahead.
        radius_iod: distance from the eyes' centre of rotation to the iris, in
            inter-ocular distances (:data:`HUMAN_RADIUS_IOD`).
    """
    offsets, opening, iod = iris_offsets(landmarks_head)
    rest_offsets, rest_opening, rest_iod = iris_offsets(np.asarray(rest)[None])
    rest = rest_offsets[0]  # (2, 3)
    rest_opening = np.maximum(rest_opening[0], 1e-6)
    radius = max(float(radius_iod) * float(rest_iod[0]), 1e-6)
    d = (offsets - rest) / radius
    pitch = np.degrees(np.arcsin(np.clip(-d[..., 1], -1.0, 1.0)))  # (F, 2)
    yaw = np.degrees(np.arcsin(np.clip(d[..., 0] / np.maximum(np.cos(np.radians(pitch)), 1e-6), -1.0, 1.0)))

    closed = opening < CLOSED_FRACTION * rest_opening  # (F, 2)
    # A closed eye takes the open one's angles (eyes move together); both closed: bridged.
    for e in (0, 1):
        use_other = closed[:, e] & ~closed[:, 1 - e]
        yaw[use_other, e] = yaw[use_other, 1 - e]
        pitch[use_other, e] = pitch[use_other, 1 - e]
    both = closed.all(1)
    for e in (0, 1):
        yaw[:, e] = _fill_closed(yaw[:, e], both)
        pitch[:, e] = _fill_closed(pitch[:, e], both)
    pitch[:] = pitch.mean(1, keepdims=True)
    out = np.stack([yaw, pitch], -1)
    return np.clip(np.nan_to_num(out), -MAX_DEG, MAX_DEG).astype(np.float32)


def eye_radius_iod(rig) -> float:
    """Distance from a rig's eye centres to its mean iris landmark vertex, in its
    inter-ocular distances: :func:`eye_rotation`'s ``radius_iod`` for a clip of this
    character (the synthetic loop, whose actor is the default avatar)."""
    if not rig.has_eyes:
        return HUMAN_RADIUS_IOD
    r = [np.linalg.norm(landmark_points(rig, rig.vertices, list(iris)).astype(np.float64).mean(0) - rig.eye_centres[e])
         for e, (iris, _, _) in enumerate(EYES)]
    return float(np.mean(r)) / rig.interocular()

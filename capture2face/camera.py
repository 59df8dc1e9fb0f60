"""Camera maths shared by the rasterizer and the synthetic ground truth.

OpenGL convention (docs/ARCHITECTURE.md): camera at the origin looking down -z, +y up;
a head pose is a (4, 4) head -> camera transform in cm. Pixels: x right, y down, origin at
the top-left corner of the top-left pixel, pixel centres at +0.5. ``project`` is exactly
what the rasterizer does with a vertex, so landmarks projected here land on the pixels
the renderer draws them at.
"""

from __future__ import annotations

import numpy as np

from capture2face.maths.rotations import rotation_ypr  # also re-exported here: its old home
from capture2face.rig.arkit_names import is_automatic
from capture2face.rig.face_rig import FaceRig
from capture2face.topology import N_MESH

# Fraction of the frame height the face's skin fills in ``framing_pose``.
FRAMING_FILL = 0.6


def _size(size) -> tuple[int, int]:
    """``int`` or ``(width, height)`` -> ``(width, height)``."""
    if isinstance(size, (int, np.integer)):
        return int(size), int(size)
    width, height = size
    return int(width), int(height)


def perspective(fov_y_degrees: float, aspect: float, near: float, far: float) -> np.ndarray:
    """(4, 4) float64 OpenGL projection matrix (column vectors: clip = P @ camera)."""
    f = 1.0 / np.tan(np.radians(fov_y_degrees) / 2.0)
    return np.array(
        [
            [f / aspect, 0.0, 0.0, 0.0],
            [0.0, f, 0.0, 0.0],
            [0.0, 0.0, (far + near) / (near - far), 2.0 * far * near / (near - far)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )


def project(points_head: np.ndarray, head_pose: np.ndarray, fov_y_degrees: float, size) -> np.ndarray:
    """Pixel positions of head-coordinate points.

    Args:
        points_head: (N, 3) or (F, N, 3) points in head coordinates (cm).
        head_pose: (4, 4) or (F, 4, 4) head -> camera transforms.
        fov_y_degrees: vertical field of view.
        size: image ``(width, height)`` or one int for a square image.
    Returns:
        (N, 2) or (F, N, 2) float64 pixel coordinates (x right, y down, pixel centres at
        +0.5). Points behind the camera come out as NaN.
    """
    width, height = _size(size)
    pts = np.asarray(points_head, np.float64)
    pose = np.asarray(head_pose, np.float64)
    cam = pts @ np.swapaxes(pose[..., :3, :3], -1, -2) + pose[..., None, :3, 3]
    f = 1.0 / np.tan(np.radians(fov_y_degrees) / 2.0)
    depth = -cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc_x = np.where(depth > 0, f * (height / width) * cam[..., 0] / depth, np.nan)
        ndc_y = np.where(depth > 0, f * cam[..., 1] / depth, np.nan)
    return np.stack([(ndc_x + 1.0) * 0.5 * width, (1.0 - ndc_y) * 0.5 * height], axis=-1)


def rotation_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """(3, 3) head rotation from angles in degrees: ``Rz(roll) @ Ry(yaw) @ Rx(pitch)``
    (:func:`capture2face.maths.rotations.rotation_ypr` for arrays of angles).

    Positive yaw turns the face (+z) towards +x (the subject's left, the camera's right
    when facing it), positive pitch tilts it up towards +y, positive roll turns +x
    towards +y.
    """
    return rotation_ypr(np.array([yaw, pitch, roll], np.float64))


# The face mesh's landmarks (the irises' ten follow).
N_FACE_LANDMARKS = N_MESH
# A vertex that some morph moves further than this (cm) belongs to the face.
_FACE_MORPH_CM = 0.02


def face_points(rig: FaceRig) -> np.ndarray:
    """(N, 3) the points the camera frames: the skin; for an ARKit character (morphs and
    no face bones of its own, maybe on a whole body with hair and clothes, all of it
    "skin"), the face: its landmarks once they are found (the morphs of a scanned
    head also move its neck, which framed the bust), else the vertices its morphs move."""
    skin = rig.material == 0
    face = np.asarray(rig.landmark_vertices)[:N_FACE_LANDMARKS]
    found = is_automatic(rig) or rig.landmark_source not in ("", "none")  # cast on its skin at load
    if found and np.count_nonzero(face >= 0) >= 3:
        return rig.vertices[face[face >= 0]]
    if rig.n_morphs and (is_automatic(rig) or not (face >= 0).any()):
        moved = np.zeros(rig.n_vertices, bool)
        for m in range(rig.n_morphs):  # per morph: no (M, V, 3) temporary
            moved |= np.abs(rig.morph_positions[m]).max(axis=1) > _FACE_MORPH_CM
        if moved.sum() >= 3:
            return rig.vertices[moved]
    return rig.vertices[skin]


def face_centre_and_height(rig: FaceRig) -> tuple[np.ndarray, float]:
    """Centre (3,) of the face's bounding box (:func:`face_points`) and its height (cm)."""
    points = face_points(rig)
    lo, hi = points.min(0).astype(np.float64), points.max(0).astype(np.float64)
    return (lo + hi) / 2.0, float(hi[1] - lo[1])


def framing_distance(rig: FaceRig, fov_y_degrees: float) -> float:
    """Camera distance (cm, to the face's centre) at which the skin fills ``FRAMING_FILL``
    of the frame height."""
    return _fill_distance(face_centre_and_height(rig)[1], fov_y_degrees)


def _fill_distance(height: float, fov_y_degrees: float) -> float:
    return float(height / (2.0 * FRAMING_FILL * np.tan(np.radians(fov_y_degrees) / 2.0)))


def framing_pose(rig: FaceRig, yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0,
                 fov_y_degrees: float = 30.0) -> np.ndarray:
    """(4, 4) head -> camera pose that centres the face and makes its skin fill about 60%
    of the frame height (angles in degrees, see :func:`rotation_matrix`)."""
    centre, height = face_centre_and_height(rig)  # one pass over the face's points
    distance = _fill_distance(height, fov_y_degrees)
    rot = rotation_matrix(yaw, pitch, roll)
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = np.array([0.0, 0.0, -distance]) - rot @ centre
    return pose

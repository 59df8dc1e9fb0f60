"""Head-pose removal: MediaPipe's screen landmarks -> metric camera space -> head coordinates.

This is MediaPipe's own face-geometry pipeline (``geometry_pipeline.cc``, the "screen to
metric space" converter) in vectorized NumPy, over all frames at once:

1. x, y are put on the near plane of the perspective camera MediaPipe assumes (vertical
   field of view 63 degrees, near = 1 cm, origin top-left; the Tasks API uses this default
   environment); the relative z is scaled like x.
2. A weighted Procrustes fit (similarity; rotation, uniform scale, translation) of the
   canonical face onto these points, on MediaPipe's procrustes landmark basis, gives a
   first scale; the points are unprojected with it (z moved to the near plane and divided
   by the scale, x, y multiplied by z / near), fitted again, and unprojected once more
   with the product of both scales: the *metric* landmarks (cm, camera space).
3. The final fit is the head -> camera pose (it reproduces MediaPipe's facial
   transformation matrix); its inverse applied to the metric landmarks gives the
   landmarks in head coordinates. Moving or turning the head changes only the pose.

The 10 iris landmarks (468..477) ride along with the same depth offset and scale; they
take no part in the fits, exactly as in MediaPipe.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from capture2face.rig.canonical import CanonicalMesh, load_canonical_mesh
from capture2face.topology import N_MESH

FOV_Y_DEGREES = 63.0  # MediaPipe's default environment (face_geometry_from_landmarks_graph.cc)
NEAR_CM = 1.0

_mesh_cache: dict[str, CanonicalMesh] = {}


def canonical_mesh(face_model=None) -> CanonicalMesh:
    """The canonical mesh (cached per model file)."""
    key = str(face_model)
    if key not in _mesh_cache:
        _mesh_cache[key] = load_canonical_mesh(face_model)
    return _mesh_cache[key]


def weighted_procrustes(source: np.ndarray, target: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Similarity transforms mapping ``source`` onto ``target`` in the weighted least-squares sense.

    Args:
        source: (N, 3) points (the canonical face).
        target: (F, N, 3) points per frame.
        weights: (N,) non-negative weights.

    Returns:
        (F, 4, 4) float64 matrices ``[s R | t]`` with ``target ~ s R source + t``.
    """
    w = weights.astype(np.float64)
    wsum = w.sum()
    src = source.astype(np.float64)
    tgt = target.astype(np.float64)
    src_c = src - (w[:, None] * src).sum(0) / wsum  # (N, 3) weighted-centred source
    # Design matrix sum_i w_i target_i (source_i - c)^T: the target centre drops out.
    design = np.einsum("n,fni,nj->fij", w, tgt, src_c)
    u, _, vt = np.linalg.svd(design)
    flip = np.linalg.det(u) * np.linalg.det(vt) < 0
    u[flip, :, 2] *= -1.0  # no reflections
    rot = u @ vt
    num = np.einsum("fij,nj,fni,n->f", rot, src_c, tgt, w)
    den = float((w[:, None] * src_c * src).sum())
    scale = num / den
    sr = scale[:, None, None] * rot
    t = (w[None, :, None] * (tgt - np.einsum("fij,nj->fni", sr, src))).sum(1) / wsum
    out = np.zeros((target.shape[0], 4, 4))
    out[:, :3, :3] = sr
    out[:, :3, 3] = t
    out[:, 3, 3] = 1.0
    return out


def metric_landmarks(landmarks_norm: np.ndarray, width: int, height: int,
                     mesh: CanonicalMesh | None = None, fov_y: float = FOV_Y_DEGREES
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Screen landmarks -> metric camera-space landmarks and head pose (see module doc).

    Args:
        landmarks_norm: (F, L, 3) MediaPipe normalized landmarks, L = 468 or 478.

    Returns:
        metric: (F, L, 3) float64 cm, camera space (OpenGL: camera looks down -z).
        pose: (F, 4, 4) float64 head -> camera.
    """
    mesh = mesh or canonical_mesh()
    ids, wts = mesh.procrustes_ids, mesh.procrustes_weights
    canon = mesh.vertices[ids].astype(np.float64)
    height_near = 2.0 * NEAR_CM * np.tan(0.5 * np.radians(fov_y))
    width_near = width * height_near / height
    scr = np.array(landmarks_norm, np.float64, copy=True)
    scr[..., 1] = 1.0 - scr[..., 1]  # top-left origin -> y up
    scr *= np.array([width_near, height_near, width_near])
    scr[..., 0] -= 0.5 * width_near
    scr[..., 1] -= 0.5 * height_near
    depth_offset = scr[:, :N_MESH, 2].mean(1)  # (F,)

    def unproject(scale: np.ndarray) -> np.ndarray:
        pts = scr.copy()
        pts[..., 2] = (pts[..., 2] - depth_offset[:, None] + NEAR_CM) / scale[:, None]
        pts[..., :2] *= pts[..., 2:3] / NEAR_CM
        pts[..., 2] *= -1.0  # left-handed screen -> right-handed metric
        return pts

    def fit_scale(pts: np.ndarray) -> np.ndarray:
        m = weighted_procrustes(canon, pts[:, ids], wts)
        return np.linalg.norm(m[:, :3, 0], axis=1)

    first = scr.copy()
    first[..., 2] *= -1.0
    s1 = fit_scale(first)
    s2 = fit_scale(unproject(s1))
    metric = unproject(s1 * s2)
    pose = weighted_procrustes(canon, metric[:, ids], wts)
    return metric, pose


def to_head(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Camera-space points (F, L, 3) -> head coordinates through the inverse pose (F, 4, 4)."""
    inv = np.linalg.inv(pose)
    return np.einsum("fij,flj->fli", inv[:, :3, :3], points) + inv[:, None, :3, 3]


def head_landmarks(landmarks_norm: np.ndarray, width: int, height: int,
                   mesh: CanonicalMesh | None = None, fov_y: float = FOV_Y_DEGREES
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks in head coordinates (F, L, 3) cm and the head pose (F, 4, 4)."""
    metric, pose = metric_landmarks(landmarks_norm, width, height, mesh, fov_y)
    return to_head(metric, pose), pose


def project_camera_points(points: np.ndarray, width: int, height: int,
                          fov_y: float = FOV_Y_DEGREES) -> np.ndarray:
    """Camera-space points (..., 3) cm -> pixels (..., 2) through MediaPipe's camera.

    Perspective with vertical field of view ``fov_y``, the image spanning the frustum
    (x right, y down, origin at the top-left image corner); NaN behind the camera.
    """
    pts = np.asarray(points, np.float64)
    f = 1.0 / np.tan(0.5 * np.radians(fov_y))
    depth = -pts[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc_x = np.where(depth > 0, f * (height / width) * pts[..., 0] / depth, np.nan)
        ndc_y = np.where(depth > 0, f * pts[..., 1] / depth, np.nan)
    return np.stack([(ndc_x + 1.0) * 0.5 * width, (1.0 - ndc_y) * 0.5 * height], axis=-1)


def split_pose(pose: np.ndarray) -> tuple[np.ndarray, Rotation, np.ndarray]:
    """Head poses (F, 4, 4) ``[s R | t]`` -> translation (F, 3), rotations (F), scale (F,)."""
    m3 = pose[:, :3, :3]
    scale = np.cbrt(np.linalg.det(m3))
    return pose[:, :3, 3], Rotation.from_matrix(m3 / scale[:, None, None]), scale

"""A character's tracker landmarks found automatically: its neutral face rendered from the
front, tracked with the clips' tracker, each landmark cast onto the surface."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from capture2face.camera import framing_pose, project
from capture2face.errors import CaptureError
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.rig.face_rig import FaceRig
from capture2face.tracking.landmarker import FaceLandmarker, LandmarkerOptions

# The front view's size in pixels.
RENDER_SIZE = 512


def find_landmark_vertices(rig: FaceRig) -> np.ndarray:
    """(478,) int32 vertex under each MediaPipe landmark of the character's neutral face
    rendered from the front (-1 where none).

    Raises:
        CaptureError: the tracker finds no face in the render.
    """
    opts = RenderOptions(size=RENDER_SIZE, wrinkles="off", samples=4)
    pose = framing_pose(rig, fov_y_degrees=opts.fov_y_degrees)
    with Renderer(rig, opts) as renderer:
        image = renderer.render(FrameState.at_pose(rig, pose))
    with FaceLandmarker.create_from_options(LandmarkerOptions(num_faces=1)) as landmarker:
        obs = landmarker.detect(image, 0.0)
    if obs is None:
        raise CaptureError(f"character '{rig.name}': the tracker finds no face in its front view")
    px = project(rig.vertices, pose, opts.fov_y_degrees, RENDER_SIZE)  # (V, 2)
    cam = rig.vertices.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
    depth = -cam[:, 2]
    # Only vertices facing the camera: the back of a whole head projects onto the face too.
    facing = np.einsum("vc,vc->v", rig.normals.astype(np.float64) @ pose[:3, :3].T, -cam) > 0
    out = np.full(len(obs.landmarks_px), -1, np.int32)
    lm = obs.landmarks_px.astype(np.float64)
    for material, rows in ((0, slice(0, 468)), (1, slice(468, None))):  # skin; irises on the eyes
        cand = np.flatnonzero((rig.material == material) & facing & np.isfinite(px).all(1))
        if not len(cand):
            continue
        k = min(32, len(cand))
        d, idx = cKDTree(px[cand]).query(lm[rows], k=k)
        d, idx = d.reshape(len(d), k), idx.reshape(len(idx), k)
        # The front-most vertex among those within 2 px (or the nearest, if further): the
        # surface under the landmark, not the back of the head behind it.
        near = d <= np.maximum(d[:, :1], 2.0)
        front = np.where(near, depth[cand][idx], np.inf)
        out[rows] = cand[idx[np.arange(len(idx)), np.argmin(front, axis=1)]]
    return out

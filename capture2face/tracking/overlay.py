"""Overlay video: the source clip with the tracked landmarks and head axes drawn on it.

Landmarks are green where a face was detected, yellow where interpolated over a short
gap, red where held through a long gap. Head axes (5 cm; x red, y green, z blue) come from
the filtered head pose projected with MediaPipe's camera.
"""

from __future__ import annotations

import os

import cv2
import numpy as np
from tqdm import tqdm

from capture2face.io.video_input import iter_frames, prefetch
from capture2face.io.video_output import VideoWriter
from capture2face.tracking.head_pose import project_camera_points
from capture2face.tracking.track import Track

AXIS_CM = 5.0
_COLORS = {"present": (40, 220, 60), "interpolated": (240, 220, 30), "held": (230, 40, 40)}


def head_axes_px(track: Track) -> np.ndarray:
    """(F, 4, 2) pixel positions of the head origin and the tips of its x, y, z axes."""
    pts = np.array([[0, 0, 0], [AXIS_CM, 0, 0], [0, AXIS_CM, 0], [0, 0, AXIS_CM]], np.float64)
    pose = track.head_pose.astype(np.float64)
    cam = np.einsum("fij,nj->fni", pose[:, :3, :3], pts) + pose[:, None, :3, 3]
    return project_camera_points(cam, track.width, track.height, track.camera_fov_y)


def draw_frame(rgb: np.ndarray, track: Track, f: int, axes: np.ndarray | None = None) -> np.ndarray:
    """A copy of ``rgb`` (H, W, 3) with frame ``f``'s landmarks and head axes drawn."""
    img = np.ascontiguousarray(rgb).copy()
    state = "held" if track.held[f] else "interpolated" if track.interpolated[f] else "present"
    color = _COLORS[state]
    pts = np.round(track.landmarks_px[f] * 4.0).astype(np.int32)  # 2 fractional bits
    for x, y in pts:
        cv2.circle(img, (int(x), int(y)), 4, color, -1, cv2.LINE_AA, shift=2)
    ax = axes[f] if axes is not None else head_axes_px(track)[f]
    if np.isfinite(ax).all():
        o = tuple(np.round(ax[0] * 4.0).astype(int))
        for tip, c in zip(ax[1:], [(255, 0, 0), (0, 255, 0), (0, 80, 255)]):
            cv2.line(img, o, tuple(np.round(tip * 4.0).astype(int)), c, 2, cv2.LINE_AA, shift=2)
    label = f"{f}  t={track.times[f]:.2f}s  {state}" + ("  neutral" if f == track.neutral_frame else "")
    cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def write_overlay(clip: str | os.PathLike, track: Track, path: str | os.PathLike, progress: bool = True) -> int:
    """Write ``path`` (.mp4): ``clip``'s frames with ``track`` drawn; returns frames written.

    Odd frame sizes are padded by one black pixel row/column (H.264 yuv420p needs even).
    """
    w, h = track.width + track.width % 2, track.height + track.height % 2
    axes = head_axes_px(track)
    n = 0
    frames = prefetch(iter_frames(clip, max_frames=track.n_frames))
    try:
        with VideoWriter(path, track.fps, (w, h)) as out, \
                tqdm(total=track.n_frames, disable=not progress, desc="overlay", unit="frame", leave=False) as bar:
            for f, (_, rgb) in enumerate(frames):
                img = draw_frame(rgb, track, f, axes)
                if img.shape[:2] != (h, w):
                    img = np.pad(img, ((0, h - img.shape[0]), (0, w - img.shape[1]), (0, 0)))
                out.write(img)
                n += 1
                bar.update(1)
    finally:
        frames.close()
    return n

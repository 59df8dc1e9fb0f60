"""compare.mp4 frames: source with its landmarks | character | wrinkle-influence view.

Pure NumPy/OpenCV on (H, W, 3) uint8 RGB arrays (no GL); OpenCV's resize releases the
GIL, so composing runs well in the encoder thread beside the GL thread.
"""

from __future__ import annotations

import cv2
import numpy as np

LANDMARK_COLOR = np.array([60, 255, 90], np.uint8)  # tracked frame
INTERPOLATED_COLOR = np.array([255, 190, 40], np.uint8)  # gap bridged by interpolation/hold
LABEL_COLOR = (235, 235, 235)
LABELS = ("source", "character", "wrinkle influence")


class SourceFitter:
    """Letterbox source frames (h, w) into a square ``size`` panel, keeping the aspect.

    Attributes:
        scale: panel pixels per source pixel.
        offset: (2,) panel position of the source's top-left corner (x, y).
    """

    def __init__(self, width: int, height: int, size: int):
        self.size = int(size)
        self.scale = min(size / width, size / height)
        self.out_w = max(1, int(round(width * self.scale)))
        self.out_h = max(1, int(round(height * self.scale)))
        self.offset = np.array([(size - self.out_w) // 2, (size - self.out_h) // 2])
        self.src_size = (int(width), int(height))

    def fit(self, rgb: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(h, w, 3) source -> (size, size, 3) panel, black bars where the aspect differs
        (written into ``out`` when given, e.g. a slice of the compare frame)."""
        panel = np.empty((self.size, self.size, 3), np.uint8) if out is None else out
        if rgb.shape[1] != self.src_size[0] or rgb.shape[0] != self.src_size[1]:
            # A frame of another size (never in a sane clip): fit it on its own terms.
            return SourceFitter(rgb.shape[1], rgb.shape[0], self.size).fit(rgb, panel)
        x, y = self.offset
        panel[:y], panel[y + self.out_h:], panel[:, :x], panel[:, x + self.out_w:] = 0, 0, 0, 0
        if (self.out_w, self.out_h) == self.src_size:
            panel[y:y + self.out_h, x:x + self.out_w] = rgb  # same size: no resampling
        else:
            interp = cv2.INTER_AREA if self.scale < 1 else cv2.INTER_LINEAR
            panel[y:y + self.out_h, x:x + self.out_w] = cv2.resize(rgb, (self.out_w, self.out_h), interpolation=interp)
        return panel

    def to_panel(self, points_px: np.ndarray) -> np.ndarray:
        """(N, 2) source pixel coordinates -> panel pixel coordinates."""
        return np.asarray(points_px, np.float64) * self.scale + self.offset


def draw_points(image: np.ndarray, points: np.ndarray, color: np.ndarray, radius: int = 1) -> None:
    """Paint (N, 2) pixel positions as (2r+1)^2 squares into ``image`` in place
    (vectorized: one fancy-index write, no per-point calls)."""
    h, w = image.shape[:2]
    points = np.asarray(points, np.float64)
    centre = np.floor(points[np.isfinite(points).all(1)]).astype(np.int64)  # pixel centres at +0.5
    d = np.arange(-radius, radius + 1)
    dx, dy = np.meshgrid(d, d)
    xs = (centre[:, 0:1] + dx.ravel()).ravel()
    ys = (centre[:, 1:2] + dy.ravel()).ravel()
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    image[ys[inside], xs[inside]] = color


def label(image: np.ndarray, text: str, x: int = 0) -> None:
    """Small caption on a darkened strip at the top-left of the panel starting at
    column ``x``, in place."""
    scale = max(0.4, image.shape[0] / 1000.0)
    thick = 1 if image.shape[0] < 700 else 2
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    pad = max(3, h // 3)
    box = image[0:h + base + 2 * pad, x:x + w + 2 * pad]
    box //= 2
    cv2.putText(image, text, (x + pad, h + pad), cv2.FONT_HERSHEY_SIMPLEX, scale, LABEL_COLOR, thick, cv2.LINE_AA)


def compare_frame(fitter: SourceFitter, source: np.ndarray | None, landmarks_px: np.ndarray | None,
                  tracked: bool, avatar: np.ndarray, influence: np.ndarray) -> np.ndarray:
    """One compare.mp4 frame.

    Args:
        fitter: letterboxing of the source into a panel of the avatar's size.
        source: (h, w, 3) source frame (None: a black panel, e.g. past a truncated end).
        landmarks_px: (L, 2) the track's landmarks in source pixels (None: none drawn).
        tracked: the face was detected in this frame (else the landmarks are the track's
            interpolated or held values, drawn in another colour).
        avatar: (S, S, 3) rendered character.
        influence: (s, s, 3) rendered influence view, resized to S x S if smaller.
    Returns:
        (S, 3 S, 3) uint8.
    """
    s = avatar.shape[0]
    out = np.empty((s, 3 * s, 3), np.uint8)  # panels written in place: no concatenation
    panel = out[:, :s]
    if source is not None:
        fitter.fit(source, panel)
    else:
        panel[:] = 0
    if landmarks_px is not None:
        draw_points(panel, fitter.to_panel(landmarks_px), LANDMARK_COLOR if tracked else INTERPOLATED_COLOR,
                    radius=1 if s >= 384 else 0)
    out[:, s:2 * s] = avatar
    if influence.shape[:2] != (s, s):
        influence = cv2.resize(influence, (s, s), interpolation=cv2.INTER_LINEAR)
    out[:, 2 * s:] = influence
    for k, text in enumerate(LABELS):
        label(out, text, k * s)
    return out

"""The poster frames of report.html: where the expression is strongest, decoded and encoded
as JPEG data URIs."""

from __future__ import annotations

import base64
import os
from collections.abc import Sequence

import numpy as np

from capture2face.io.video_input import iter_frames

# Poster cues: label -> ARKit curves whose mean picks the frame.
POSTER_CUES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("jawOpen", ("jawOpen",)),
    ("smile", ("mouthSmileLeft", "mouthSmileRight")),
    ("browInnerUp", ("browInnerUp",)),
    ("browDown", ("browDownLeft", "browDownRight")),
    ("eyeBlink", ("eyeBlinkLeft", "eyeBlinkRight")),
    ("mouthPucker", ("mouthPucker",)),
)


POSTER_MIN_SCORE = 0.15  # a cue whose strongest frame scores less shows nothing worth a poster
POSTER_WIDTH = 900  # px, the JPEGs' largest width
POSTER_QUALITY = 80


def curve_index(names: Sequence[str]) -> dict[str, int]:
    return {str(n).lower(): i for i, n in enumerate(names)}


def report_curves(animation, track=None) -> tuple[np.ndarray, list[str], str]:
    """(F, A) ARKit curves, their names and where they come from ("animation": the
    retargeted ``Animation.arkit_weights``; else "tracker": MediaPipe's scores)."""
    weights = getattr(animation, "arkit_weights", None)
    if weights is not None:
        return np.asarray(weights), list(animation.arkit_names), "animation"
    if animation is not None and getattr(animation, "mediapipe_blendshapes", None) is not None:
        return np.asarray(animation.mediapipe_blendshapes), list(animation.mediapipe_blendshape_names), "tracker"
    return np.asarray(track.blendshapes), list(track.blendshape_names), "tracker"


def choose_poster_frames(curves: np.ndarray, names: Sequence[str], presence: np.ndarray | None = None,
                         neutral: int | None = None, count: int = 6) -> list[tuple[int, str]]:
    """Up to ``count`` (frame, reason) pairs, sorted by frame: the neutral frame, then the
    frame where each :data:`POSTER_CUES` curve peaks (frames closer than 1/12 of the clip
    to one already chosen are skipped), filled with evenly spread frames to at least 4."""
    curves = np.asarray(curves)  # (F, A) as stored (float32): no whole-clip float64 copy
    n = len(curves)
    if n == 0:
        return []
    gap = max(1, n // 12)
    valid = np.ones(n, bool) if presence is None else np.asarray(presence, bool)[:n].copy()
    taken = np.zeros(n, bool)
    chosen: list[tuple[int, str]] = []

    def take(i: int, why: str) -> None:
        chosen.append((int(i), why))
        taken[max(0, i - gap):i + gap + 1] = True

    if neutral is not None and 0 <= neutral < n:
        take(int(neutral), "neutral")
    index = curve_index(names)
    for label, cue in POSTER_CUES:
        if len(chosen) >= count:
            break
        cols = [index[c.lower()] for c in cue if c.lower() in index]
        if not cols:
            continue
        score = curves[:, cols].mean(1)
        score = np.where(valid & ~taken & np.isfinite(score), score, -np.inf)
        i = int(np.argmax(score))
        if score[i] >= POSTER_MIN_SCORE:
            take(i, f"{label} {score[i]:.2f}")
    for i in np.linspace(0, n - 1, max(2, count)).round().astype(int):
        if len(chosen) >= min(4, count):
            break
        if not taken[i]:
            take(int(i), "spread")
    return sorted(chosen)


def poster_frames(animation, neutral: int | None = None, count: int = 6) -> list[tuple[int, str]]:
    """:func:`choose_poster_frames` of a run's animation (what ``run`` keeps while rendering)."""
    curves, names, _ = report_curves(animation)
    return choose_poster_frames(curves, names, animation.presence, neutral, count)


def decode_poster_frames(video: str | os.PathLike, frames: Sequence[int],
                         max_width: int = POSTER_WIDTH) -> dict[int, np.ndarray]:
    """frame index -> RGB image of the wanted frames of ``video`` (the project's decoder;
    stops after the last wanted one), scaled down to ``max_width``."""
    wanted = {int(i) for i in frames}
    out: dict[int, np.ndarray] = {}
    if not wanted:
        return out
    for i, (_, rgb) in enumerate(iter_frames(video, max_frames=max(wanted) + 1)):
        if i in wanted:
            out[i] = shrink(rgb, max_width)
    return out


def shrink(rgb: np.ndarray, max_width: int = POSTER_WIDTH) -> np.ndarray:
    import cv2

    h, w = rgb.shape[:2]
    if w <= max_width:
        return rgb
    return cv2.resize(rgb, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)


def jpeg_data_uri(rgb: np.ndarray, quality: int = POSTER_QUALITY) -> str:
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode("ascii")

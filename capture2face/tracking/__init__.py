"""Tracking: a recorded clip becomes a head-stabilized feature-point :class:`Track`.

``track_clip(clip, TrackOptions()) -> Track`` decodes the clip (:mod:`.video`), runs
MediaPipe's Face Landmarker on every frame (:mod:`.landmarker`), expresses the landmarks
in head coordinates (:mod:`.head_pose`), fills gaps (:mod:`.gaps`), smooths landmarks and
pose with a One Euro filter (:mod:`.filtering`) and picks the neutral frame
(:mod:`.neutral`). :class:`Tracker` is the streaming form: ``process(t, rgb)`` per frame,
``finish() -> Track`` at the end, so a caller can decode once and share frames.

The driver (:class:`TrackOptions`, :class:`Tracker`, :class:`TrackBuilder`,
:func:`track_clip`) lives in :mod:`capture2face.tracking.tracker`; this package
re-exports it. Patch names there (e.g. ``FLUSH_FRAMES``), where they are used.
"""

from __future__ import annotations

import importlib

# Names are imported on first use (as in capture2face/__init__): a segment worker
# (:mod:`.segments`) imports only the landmarker and the decoder, not SciPy.
_API = {
    "CaptureError": "capture2face.errors",
    "FrameArray": "capture2face.io.framestore",
    "CausalOneEuro": "capture2face.tracking.filtering",
    "OneEuro": "capture2face.tracking.filtering",
    "filter_pose": "capture2face.tracking.filtering",
    "fill_pose": "capture2face.tracking.gaps",
    "plan_gaps": "capture2face.tracking.gaps",
    "FOV_Y_DEGREES": "capture2face.tracking.head_pose",
    "canonical_mesh": "capture2face.tracking.head_pose",
    "head_landmarks": "capture2face.tracking.head_pose",
    "BLENDSHAPE_NAMES": "capture2face.topology",
    "N_LANDMARKS": "capture2face.topology",
    "FaceLandmarker": "capture2face.tracking.landmarker",
    "FaceObservation": "capture2face.tracking.landmarker",
    "LandmarkerOptions": "capture2face.tracking.landmarker",
    "pick_neutral": "capture2face.tracking.neutral",
    "Track": "capture2face.tracking.track",
    "FLUSH_FRAMES": "capture2face.tracking.tracker",
    "WINDOW_FRAMES": "capture2face.tracking.tracker",
    "TrackBuilder": "capture2face.tracking.tracker",
    "Tracker": "capture2face.tracking.tracker",
    "TrackOptions": "capture2face.tracking.options",
    "build_track": "capture2face.tracking.tracker",
    "track_clip": "capture2face.tracking.tracker",
    "VideoInfo": "capture2face.io.video_input",
    "iter_frames": "capture2face.io.video_input",
    "open_video": "capture2face.io.video_input",
    "prefetch": "capture2face.io.video_input",
}

__all__ = ["Track", "TrackOptions", "Tracker", "TrackBuilder", "build_track", "track_clip", "open_video",
           "iter_frames", "VideoInfo"]


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'capture2face.tracking' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))

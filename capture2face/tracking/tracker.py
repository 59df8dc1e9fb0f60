"""The tracking driver: the streaming :class:`Tracker`, the
bounded-memory :class:`TrackBuilder` and :func:`track_clip` (the stage is described in
:mod:`capture2face.tracking`)."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture2face.errors import CaptureError, NoFaceError, raise_if_interrupted
from capture2face.io.framestore import FrameArray
from capture2face.io.video_input import VideoInfo, iter_frames, open_video, prefetch
from capture2face.topology import BLENDSHAPE_NAMES, N_LANDMARKS
from capture2face.tracking.calibration import calibrated, neutral_take, take_rest
from capture2face.tracking.filtering import CausalOneEuro, filter_pose
from capture2face.tracking.gaps import fill_pose, plan_gaps
from capture2face.tracking.head_pose import (
    FOV_Y_DEGREES,
    canonical_mesh,
    head_landmarks,
)
from capture2face.tracking.landmarker import (
    FaceLandmarker,
    FaceObservation,
    stack_observations,
)
from capture2face.tracking.neutral import pick_neutral
from capture2face.tracking.options import TrackOptions
from capture2face.tracking.rest import GEOMETRY, clip_rest, frame_rest, rest_fields, rest_geometry
from capture2face.tracking.segments import track_parallel
from capture2face.tracking.track import Track

FLUSH_FRAMES = 256  # frames converted to head coordinates (and written to disk) at a time
WINDOW_FRAMES = 256  # frames per window of the gap-fill and filter passes (the filter
# loops over frames anyway: a small window costs nothing and keeps temporaries small)


def head_block(norm: np.ndarray, presence: np.ndarray, size: tuple[int, int], face_model=None
               ) -> tuple[np.ndarray, np.ndarray]:
    """MediaPipe's landmarks ``norm`` (k, 478, 3) of ``size`` (W, H) images -> head
    coordinates (k, 478, 3) float64 and head -> camera poses (k, 4, 4); rows without a
    face (``presence`` False) are zeros and identity poses."""
    width, height = size
    idx = np.flatnonzero(presence)
    head = np.zeros((len(norm), N_LANDMARKS, 3))
    pose = np.tile(np.eye(4), (len(norm), 1, 1))
    if idx.size:
        head[idx], pose[idx] = head_landmarks(np.asarray(norm[idx], np.float64), width, height,
                                              canonical_mesh(face_model))
    return head, pose


class TrackBuilder:
    """Per-frame observations in, :class:`Track` out, in memory bounded whatever the
    clip's length (~300 bytes a frame).

    Every :data:`FLUSH_FRAMES` frames the landmarks are put in head coordinates and
    appended to raw files in a work folder (:mod:`capture2face.io.framestore`); only the
    blendshape scores, head poses and times stay in RAM. :meth:`finish` fills gaps and
    filters window by window. With ``workdir`` the Track's landmark arrays are read-only
    :class:`~capture2face.io.framestore.FrameArray` files in that folder (valid as long as
    it is); without, a private temporary folder is used and the Track holds ordinary
    arrays.
    """

    def __init__(self, info: VideoInfo, options: TrackOptions | None = None,
                 workdir: str | os.PathLike | None = None):
        self.info = info
        self.options = options or TrackOptions()
        self._own_dir = workdir is None
        self._dir = Path(tempfile.mkdtemp(prefix="capture2face-track-") if workdir is None else workdir)
        self._dir.mkdir(parents=True, exist_ok=True)
        self._norm = FrameArray(self._dir / "raw_norm.f32", (N_LANDMARKS, 3), np.float32)
        self._head = FrameArray(self._dir / "raw_head.f64", (N_LANDMARKS, 3), np.float64)
        self._pending: list[FaceObservation | None] = []
        self._times: list[float] = []
        self._presence: list[np.ndarray] = []
        self._scores: list[np.ndarray] = []
        self._pose: list[np.ndarray] = []
        self._n_faces_max = 0
        self.size: tuple[int, int] | None = None

    @property
    def n_frames(self) -> int:
        return len(self._times)

    def check_size(self, size: tuple[int, int]) -> None:
        """Raise CaptureError when ``size`` (W, H) is not the clip's frame size so far."""
        if self.size is not None and size != self.size:
            raise CaptureError(f"{self.info.path}: frame size changes mid-clip "
                               f"({self.size[0]}x{self.size[1]} -> {size[0]}x{size[1]})")

    def add(self, t: float, obs: FaceObservation | None, size: tuple[int, int]) -> None:
        """One frame at time ``t`` seconds: its face (or None) in a ``size`` (W, H) image."""
        self.check_size(size)
        self.size = size
        self._times.append(float(t))
        self._pending.append(obs)
        if len(self._pending) >= FLUSH_FRAMES:
            self._flush()

    def _flush(self) -> None:
        """Pending frames -> head coordinates on disk; scores and poses kept in RAM."""
        obs, self._pending = self._pending, []
        if obs:
            block = stack_observations(obs)
            self._append(block["norm"], block["presence"], block["scores"], block["n_faces_max"])

    def _append(self, norm: np.ndarray, presence: np.ndarray, scores: np.ndarray, n_faces_max: int) -> None:
        head, pose = head_block(norm, presence, self.size, self.options.landmarker.face_model)
        self._norm.append(norm)
        self._head.append(head)
        self._presence.append(np.asarray(presence, bool))
        self._scores.append(np.asarray(scores, np.float64))
        self._pose.append(pose)
        self._n_faces_max = max(self._n_faces_max, int(n_faces_max))

    def extend(self, times: np.ndarray, norm, presence: np.ndarray, scores: np.ndarray, n_faces_max: int,
               size: tuple[int, int]) -> None:
        """Frames tracked elsewhere (a segment's worker, :mod:`.segments`), after those
        added so far: times (k,), MediaPipe's landmarks ``norm`` (k, 478, 3) (an array or
        a :class:`FrameArray`, read a bounded block at a time), presence (k,), scores
        (k, 52) and the most faces seen at once."""
        self.check_size(size)
        self.size = size
        self._flush()
        for s in range(0, len(times), FLUSH_FRAMES):
            e = min(len(times), s + FLUSH_FRAMES)
            self._append(np.asarray(norm[s:e], np.float32), presence[s:e], scores[s:e], n_faces_max)
        self._times.extend(np.asarray(times, np.float64).tolist())

    def close(self) -> None:
        """Drop the raw files (and the private work folder)."""
        for f in (self._norm, self._head):
            f.close()
        if self._own_dir:
            shutil.rmtree(self._dir, ignore_errors=True)

    def finish(self, progress: bool = False) -> Track:
        """Build the :class:`Track` from the frames added so far.

        Raises:
            CaptureError: no frame, or no face in any frame.
        """
        try:
            return self._finish(progress)
        finally:
            self.close()

    def _finish(self, progress: bool) -> Track:
        self._flush()
        n = len(self._times)
        if n == 0:
            raise CaptureError(f"{self.info.path}: no frames to track")
        presence = np.concatenate(self._presence)
        if not presence.any():
            raise NoFaceError(f"{self.info.path}: no face found in {n} frames")
        options = self.options
        width, height = self.size  # set by the first add(); n > 0 here
        t = np.asarray(self._times, np.float64)
        scores = np.concatenate(self._scores)
        pose = np.concatenate(self._pose)
        self._scores, self._pose = [], []

        gaps = plan_gaps(t, presence, options.max_gap_seconds)
        gaps.fill(scores)
        fill_pose(gaps, pose)
        pose_f = filter_pose(pose, t, options.pose_filter())

        if options.neutral_frame is not None:
            neutral = int(options.neutral_frame)
            if not 0 <= neutral < n:
                raise CaptureError(f"--neutral-frame {neutral} is outside the clip (0..{n - 1})")
        landmarks, geometry = self._landmark_passes(t, gaps, width, height, progress)
        if options.neutral_frame is None:
            gap = geometry[:, GEOMETRY.index("lip_gap")]
            neutral = pick_neutral(scores, BLENDSHAPE_NAMES, pose_f, t, presence, mouth_gap=gap)
            rest = clip_rest(landmarks["head"], scores, BLENDSHAPE_NAMES, pose_f, t, presence, geometry)
        else:
            rest = frame_rest(landmarks["head"], scores, BLENDSHAPE_NAMES, neutral)

        return Track(
            times=t,
            landmarks_px=landmarks["px"],
            landmarks_depth=landmarks["depth"],
            landmarks_head=landmarks["head"],
            presence=presence,
            interpolated=gaps.interpolated,
            held=gaps.held,
            blendshapes=np.clip(scores, 0.0, 1.0).astype(np.float32),
            blendshape_names=list(BLENDSHAPE_NAMES),
            head_pose=pose_f.astype(np.float32),
            neutral_frame=neutral,
            width=int(width),
            height=int(height),
            fps=float(self.info.fps),
            source=str(self.info.path),
            n_faces_max=int(self._n_faces_max),
            n_gaps=gaps.n_gaps,
            n_long_gaps=gaps.n_long_gaps,
            camera_fov_y=FOV_Y_DEGREES,
            **rest_fields(rest),
        )

    def _landmark_passes(self, t: np.ndarray, gaps, width: int, height: int,
                         progress: bool) -> tuple[dict, np.ndarray]:
        """Gap-fill and filter the landmarks on disk window by window: a forward pass
        (pixels, depth, causal filter of the head-coordinate landmarks) and, for the
        zero-phase filter, a backward one. Returns the three landmark arrays and the
        filtered landmarks' rest geometry (F, 4) (:func:`~capture2face.tracking.rest.rest_geometry`,
        taken from each window as it is written: the rest needs no second read)."""
        n = len(t)
        d = self._dir
        px = FrameArray(d / "landmarks_px.f32", (N_LANDMARKS, 2), np.float32)
        depth = FrameArray(d / "landmarks_depth.f32", (N_LANDMARKS,), np.float32)
        zero_phase = self.options.zero_phase
        head = FrameArray(d / "landmarks_head.f32", (N_LANDMARKS, 3), np.float32)
        forward = FrameArray(d / "head_forward.f64", (N_LANDMARKS, 3), np.float64) if zero_phase else head
        params = self.options.landmark_filter()
        windows = [(s, min(n, s + WINDOW_FRAMES)) for s in range(0, n, WINDOW_FRAMES)]
        scale = np.array([width, height], np.float64)
        geometry = np.empty((n, len(GEOMETRY)))
        bar = tqdm(total=len(windows) * (2 if zero_phase else 1), disable=not progress or len(windows) < 4,
                   desc="filtering", unit="window", leave=False)
        with bar:
            causal = CausalOneEuro(params, speed_axis=-1)
            for s, e in windows:
                norm = gaps.fill_window(self._norm.read_rows, s, e)
                px.write(s, norm[..., :2] * scale)
                depth.write(s, norm[..., 2] * width)
                filtered = causal(gaps.fill_window(self._head.read_rows, s, e), t[s:e])
                forward.write(s, filtered)
                if not zero_phase:
                    geometry[s:e] = rest_geometry(filtered.astype(np.float32))  # as stored
                bar.update(1)
            if zero_phase:  # the same filter run backward in time over the forward result
                causal = CausalOneEuro(params, speed_axis=-1)
                for s, e in reversed(windows):
                    filtered = causal(forward.read(s, e)[::-1], -t[s:e][::-1])[::-1]
                    head.write(s, filtered)
                    geometry[s:e] = rest_geometry(filtered.astype(np.float32))  # as stored
                    bar.update(1)
        for f in (self._norm, self._head, forward if zero_phase else None):
            if f is not None:
                f.close()
                os.unlink(f.path)
        out = {"px": px, "depth": depth, "head": head}
        # A notebook's Track gets plain arrays (its folder goes); the pipeline's stays on disk.
        result = {k: np.asarray(v) if self._own_dir else v.reopen_readonly() for k, v in out.items()}
        for v in out.values():
            v.close()
        return result, geometry


class Tracker:
    """Streaming tracker: feed frames in time order, then :meth:`finish` builds the Track
    (memory bounded whatever the clip's length: see :class:`TrackBuilder`).

    >>> with Tracker(open_video(clip), TrackOptions()) as tracker:
    ...     for t, rgb in iter_frames(clip):
    ...         tracker.process(t, rgb)
    ...     track = tracker.finish()
    """

    def __init__(self, info: VideoInfo, options: TrackOptions | None = None,
                 workdir: str | os.PathLike | None = None):
        self.info = info
        self.options = options or TrackOptions()
        self._landmarker = FaceLandmarker.create_from_options(self.options.landmarker)
        self._builder = TrackBuilder(info, self.options, workdir)

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._landmarker.close()
        self._builder.close()

    @property
    def n_frames(self) -> int:
        return self._builder.n_frames

    @property
    def n_faces_max(self) -> int:
        """The most faces seen at once so far."""
        return max(self._builder._n_faces_max, self._landmarker.n_faces_max)

    def process(self, t: float, rgb: np.ndarray) -> FaceObservation | None:
        """Track one frame (H, W, 3) uint8 at time ``t`` seconds; returns its face or None."""
        size = (rgb.shape[1], rgb.shape[0])
        self._builder.check_size(size)
        obs = self._landmarker.detect(rgb, t)
        self._builder.add(t, obs, size)
        return obs

    def extend(self, *args) -> None:
        """Append frames tracked by another landmarker (:meth:`TrackBuilder.extend`)."""
        self._builder.extend(*args)

    def finish(self, progress: bool = False) -> Track:
        """Build the :class:`Track` from the frames processed so far.

        Raises:
            CaptureError: no frame, or no face in any frame.
        """
        lm = self._landmarker
        lm.close()
        self._builder._n_faces_max = max(self._builder._n_faces_max, lm.n_faces_max)
        if self.options.landmarker.face is not None and not lm.chosen and self.n_frames:
            self._builder.close()
            raise CaptureError(f"{self.info.path}: --face {self.options.landmarker.face}: never more than "
                               f"{lm.n_faces_max} face(s) in view at once (faces are numbered from 0, "
                               "left to right)")
        return self._builder.finish(progress)


def build_track(times: list[float], obs: list[FaceObservation | None], size: tuple[int, int],
                info: VideoInfo, options: TrackOptions) -> Track:
    """Per-frame observations -> head coordinates, gaps filled, filtered, neutral picked
    (an in-memory Track)."""
    builder = TrackBuilder(info, options)
    for t, o in zip(times, obs):
        builder.add(t, o, size)
    return builder.finish()


def track_clip(clip: str | os.PathLike, options: TrackOptions | None = None, progress: bool = True,
               workdir: str | os.PathLike | None = None, workers=None, info: VideoInfo | None = None) -> Track:
    """Track every frame of ``clip`` into a :class:`Track` (tqdm bar when ``progress``).

    ``workdir``: a folder for the landmark files of a long clip; the Track's landmark
    arrays are then read from there (see :class:`TrackBuilder`). None: an in-memory Track.
    ``workers``: :class:`~.segments.SegmentWorkers` started ahead for a segment-parallel
    track (:attr:`TrackOptions.workers`; None: started here when the clip is split).
    ``info``: the clip's :func:`open_video` probe, when the caller has it (else probed here).
    With ``options.neutral_image`` or ``neutral_clip`` that take is tracked first and the
    Track rests on it (:mod:`.calibration`).

    Raises:
        CaptureError: unreadable clip, no model, or no face anywhere.
    """
    options = options or TrackOptions()
    take = neutral_take(options)
    # The neutral take first: a photo without a face fails before the clip is tracked.
    rest = take_rest(*take, options, lambda p, o: track_clip(p, o, progress=False)) if take else None
    info = open_video(clip) if info is None else info
    n_workers = options.n_workers()
    track = None
    if n_workers > 1:
        track = track_parallel(clip, info, options, n_workers, lambda: Tracker(info, options, workdir), progress,
                               workdir, workers)
    if track is None:
        track = _track_sequential(clip, info, options, progress, workdir)
    return calibrated(track, rest) if rest is not None else track


def _track_sequential(clip, info: VideoInfo, options: TrackOptions, progress: bool, workdir) -> Track:
    """One landmarker, frame after frame."""
    total = info.n_frames if options.max_frames is None else min(info.n_frames, options.max_frames)
    frames = prefetch(iter_frames(clip, max_frames=options.max_frames))
    with Tracker(info, options, workdir) as tracker, tqdm(total=total, disable=not progress, unit="frame",
                                                  desc="tracking", leave=False) as bar:
        try:
            for t, rgb in frames:
                raise_if_interrupted()
                tracker.process(t, rgb)
                bar.update(1)
        finally:
            frames.close()
        return tracker.finish(progress)

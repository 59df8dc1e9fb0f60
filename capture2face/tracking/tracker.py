"""The tracking driver: :class:`TrackOptions`, the streaming :class:`Tracker`, the
bounded-memory :class:`TrackBuilder` and :func:`track_clip` (the stage is described in
:mod:`capture2face.tracking`)."""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError, raise_if_interrupted
from capture2face.io.framestore import FrameArray
from capture2face.tracking.filtering import CausalOneEuro, OneEuro, filter_pose
from capture2face.tracking.gaps import fill_pose, plan_gaps
from capture2face.tracking.head_pose import FOV_Y_DEGREES, canonical_mesh, head_landmarks
from capture2face.tracking.landmarker import (
    BLENDSHAPE_NAMES, FACE_CHOICES, MAX_FACE, N_LANDMARKS, FaceLandmarker, FaceObservation, LandmarkerOptions,
    stack_observations,
)
from capture2face.tracking.neutral import mouth_gap, pick_neutral
from capture2face.tracking.track import Track
from capture2face.tracking.video import VideoInfo, iter_frames, open_video, prefetch


@dataclass
class TrackOptions:
    """How a clip is tracked.

    Attributes:
        face_model: ``face_landmarker.task`` path (None: $CAPTURE2FACE_FACE_MODEL, else the
            copy bundled in capture2face/models).
        neutral_frame: index of the neutral frame (None: picked automatically).
        num_faces: the most faces MediaPipe looks for (and counts) at once; 1: one face,
            no choice, no count. Several cost little: see :mod:`.landmarker`.
        faces: which face starts the track when several are in view: "largest" or
            "center" (nearest the image centre); the one continuing it is followed.
        face: instead, the face with this index (0-based, left to right) in the first
            frame with more than ``face`` faces (earlier frames count as faceless).
        min_detection_confidence, min_presence_confidence, min_tracking_confidence:
            MediaPipe's thresholds.
        max_gap_seconds: gaps up to this long are interpolated; longer ones hold.
        min_cutoff, beta, d_cutoff: One Euro filter of the head-coordinate landmarks
            (Hz, 1/cm, Hz); see :mod:`.filtering`.
        pose_min_cutoff, pose_beta: One Euro filter of the head pose (Hz, 1/cm).
        zero_phase: filter forward and backward (no lag; the whole clip is known).

    Landmark filter defaults are chosen on the real clips of ../shared/clips (the
    pose filter's on ``python -m capture2face.tracking.tuning``'s synthetic clips). The
    synthetic tuning (min_cutoff 0.5 Hz, beta 0.2) kept only 0.65-0.90 of the mouth's and
    0.7-0.8 of the eyes' motion on real faces (fast speech and blinks, which the synthetic
    performances lack). Over the six clips (``capture2face eval fidelity``, lip-closed
    neutral): faithful measures 16/33 -> 28/33, mean r 0.89 -> 0.95, mean |log gain|
    0.19 -> 0.10; jitter (median second difference of the landmarks, IOD) 0.0003 ->
    0.0011 against 0.0055 unfiltered. Settings with more jitter (min_cutoff 2-3 Hz or
    beta 2-3) gain no more than one measure.
        max_frames: track only the first N frames (None: all).
        workers: landmarkers tracking segments of the clip at once, each in a process of
            its own (:mod:`.segments`); None: one per free core; 1: one landmarker, this
            process. A clip shorter than two segments, or tracked with ``face``, is
            tracked by one. The Track is the same within MediaPipe's noise.
    """

    face_model: str | os.PathLike | None = None
    neutral_frame: int | None = None
    num_faces: int = 4
    faces: str = "largest"
    face: int | None = None
    min_detection_confidence: float = 0.5
    min_presence_confidence: float = 0.5
    min_tracking_confidence: float = 0.5
    max_gap_seconds: float = 0.25
    min_cutoff: float = 1.5
    beta: float = 1.0
    d_cutoff: float = 1.0
    pose_min_cutoff: float = 2.0
    pose_beta: float = 0.0
    zero_phase: bool = True
    max_frames: int | None = None
    workers: int | None = None

    def validate(self) -> None:
        """The face choice, workers and neutral frame: one line ``CaptureError`` each, named
        after the command line's flags. The one home of these bounds (``RunOptions``,
        ``FaceLandmarker`` and the CLI ask it); the neutral frame's upper bound needs the
        clip (:func:`capture2face.preflight.check_neutral_frame`)."""
        if self.neutral_frame is not None and int(self.neutral_frame) < 0:
            raise CaptureError(f"--neutral-frame must be >= 0 (got {self.neutral_frame})")
        if self.faces not in FACE_CHOICES:
            raise CaptureError(f"--faces must be one of {', '.join(FACE_CHOICES)} (got {self.faces!r})")
        if self.face is not None and not 0 <= int(self.face) <= MAX_FACE:
            raise CaptureError(f"--face must be 0..{MAX_FACE} (got {self.face})")
        if self.workers is not None and int(self.workers) < 1:
            raise CaptureError(f"--track-workers must be >= 1 (got {self.workers})")

    def landmarker_options(self) -> LandmarkerOptions:
        return LandmarkerOptions(
            face_model=self.face_model, num_faces=self.num_faces, faces=self.faces, face=self.face,
            min_detection_confidence=self.min_detection_confidence,
            min_presence_confidence=self.min_presence_confidence,
            min_tracking_confidence=self.min_tracking_confidence,
        )

    def landmark_filter(self) -> OneEuro:
        return OneEuro(self.min_cutoff, self.beta, self.d_cutoff, self.zero_phase)

    def pose_filter(self) -> OneEuro:
        return OneEuro(self.pose_min_cutoff, self.pose_beta, self.d_cutoff, self.zero_phase)

    def n_workers(self) -> int:
        """Landmarkers at once (:attr:`workers`, None resolved to the free cores)."""
        from capture2face.tracking.segments import free_cores

        return max(1, int(self.workers)) if self.workers is not None else free_cores()


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
        head, pose = head_block(norm, presence, self.size, self.options.face_model)
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
            raise CaptureError(f"{self.info.path}: no face found in {n} frames")
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
        landmarks, gap = self._landmark_passes(t, gaps, width, height, progress)
        if options.neutral_frame is None:
            neutral = pick_neutral(scores, BLENDSHAPE_NAMES, pose_f, t, presence, mouth_gap=gap)

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
        )

    def _landmark_passes(self, t: np.ndarray, gaps, width: int, height: int,
                         progress: bool) -> tuple[dict, np.ndarray]:
        """Gap-fill and filter the landmarks on disk window by window: a forward pass
        (pixels, depth, causal filter of the head-coordinate landmarks) and, for the
        zero-phase filter, a backward one. Returns the three landmark arrays and the
        filtered landmarks' lip gap (F,) (:func:`~capture2face.tracking.neutral.mouth_gap`,
        taken from each window as it is written: the neutral pick needs no second read)."""
        from tqdm import tqdm

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
        gap = np.empty(n)
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
                    gap[s:e] = mouth_gap(filtered.astype(np.float32))  # as stored
                bar.update(1)
            if zero_phase:  # the same filter run backward in time over the forward result
                causal = CausalOneEuro(params, speed_axis=-1)
                for s, e in reversed(windows):
                    filtered = causal(forward.read(s, e)[::-1], -t[s:e][::-1])[::-1]
                    head.write(s, filtered)
                    gap[s:e] = mouth_gap(filtered.astype(np.float32))  # as stored
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
        return result, gap


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
        self._landmarker = FaceLandmarker.create_from_options(self.options.landmarker_options())
        self._builder = TrackBuilder(info, self.options, workdir)

    def __enter__(self) -> "Tracker":
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
        if self.options.face is not None and not lm.chosen and self.n_frames:
            self._builder.close()
            raise CaptureError(f"{self.info.path}: --face {self.options.face}: never more than "
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

    Raises:
        CaptureError: unreadable clip, no model, or no face anywhere.
    """
    from capture2face.tracking.segments import track_parallel

    options = options or TrackOptions()
    info = open_video(clip) if info is None else info
    n_workers = options.n_workers()
    if n_workers > 1:
        track = track_parallel(clip, info, options, n_workers, progress, workdir, workers)
        if track is not None:
            return track
    return _track_sequential(clip, info, options, progress, workdir)


def _track_sequential(clip, info: VideoInfo, options: TrackOptions, progress: bool, workdir) -> Track:
    """One landmarker, frame after frame."""
    from tqdm import tqdm

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

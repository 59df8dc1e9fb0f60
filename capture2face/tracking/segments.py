"""Segment-parallel tracking: one clip, several MediaPipe landmarkers at once.

MediaPipe's Face Landmarker runs a frame on one core, and in VIDEO mode each frame
depends on the one before (the face's region is taken from the previous landmarks), so
one landmarker cannot be spread over cores. The clip is cut into contiguous segments
instead, one per worker: this process tracks the first (streaming into the
:class:`~capture2face.tracking.tracker.TrackBuilder`, as the sequential tracker does) and
each other segment is tracked by a landmarker of its own in a process of its own
(:class:`SegmentWorkers`, started ahead of the work so the import and the model load
overlap the caller's other work). A worker starts :data:`WARMUP_FRAMES` before its
segment, on the frames the previous segment ends with, so that its landmarker has found
the face and settled into tracking it when the segment starts; those warm-up frames are
dropped. Workers write head coordinates to files beside the builder's, and the builder
appends them: gap filling, filtering and the neutral pick then run once over the whole
stitched clip, exactly as for a sequential track.

What stitching checks, falling back to the sequential tracker (whole clip) when a check
fails, so the result never depends on how the clip was cut:

* the clip's packets give every frame's timestamp (:func:`~.video.frame_times`: all
  present, strictly increasing, as many as the container lists; damaged data fails here);
* every segment decodes exactly the frames planned for it, without a decode error;
* across each cut, the worker followed the same face as the segment before it (its
  warm-up faces lie where the previous segment's faces are, within a tenth of the face
  size); with faces in view on neither side and several faces in the clip, it cannot be
  told, and the clip is tracked sequentially.

``--face N`` (the Nth face from the left, chosen at its first appearance) is always
sequential: a worker cannot know what was chosen before its segment.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np
from tqdm import tqdm

from capture2face.errors import CaptureError, raise_if_interrupted
from capture2face.io.framestore import FrameArray
from capture2face.io.video_input import (
    FrameTimes,
    VideoInfo,
    frame_times,
    iter_frames,
    iter_segment,
    prefetch,
)
from capture2face.topology import N_LANDMARKS
from capture2face.tracking.landmarker import (
    FaceLandmarker,
    LandmarkerOptions,
    defer_pyplot,
    face_boxes,
    stack_observations,
)

log = logging.getLogger("capture2face")

#: Frames each worker tracks before its segment and drops: the landmarker finds the face
#: (detector), then tracks it from frame to frame and settles on the single-face model
#: (:mod:`.landmarker`: 15 frames); landmarks then agree with an uncut track to within
#: MediaPipe's own frame-to-frame noise.
WARMUP_FRAMES = 20
#: No segment shorter than this: a worker costs its warm-up and ~1 s of start-up (hidden
#: behind ``run``'s checks where cores are free); 300 frames make 2 segments on 2 cores,
#: 5 on 16.
MIN_SEGMENT_FRAMES = 60
#: Extra frames for this process's segment when the workers are not ready yet (they
#: import MediaPipe and load the model: ~1 s).
STARTUP_FRAMES = 60
_SAME_FACE = 0.1  # centre distance / face size within which two tracks follow one face
_PROGRESS_EVERY = 16
_FLUSH_FRAMES = 256  # frames a worker holds before writing them


@dataclass
class SegmentPlan:
    """Where the clip is cut.

    Attributes:
        starts: (K + 1,) frame index where each segment starts, then the frame count.
        times: the clip's :class:`~.video.FrameTimes` (all its frames, beyond the count too).
    """

    starts: np.ndarray
    times: FrameTimes

    @property
    def n_segments(self) -> int:
        return len(self.starts) - 1

    def job(self, k: int, clip: str, rotation: int, size: tuple[int, int], folder: str, face_model) -> dict:
        """What worker ``k`` (>= 1) is asked: its frames' pts range, warm-up included."""
        pts = self.times.pts
        s, e = int(self.starts[k]), int(self.starts[k + 1])
        return {"k": k, "clip": clip, "rotation": rotation, "size": size, "folder": folder,
                "face_model": face_model, "frames": e - s,
                "first_pts": int(pts[max(0, s - WARMUP_FRAMES)]), "start_pts": int(pts[s]),
                "stop_pts": int(pts[e]) if e < len(pts) else None}


def plan_segments(clip: str | os.PathLike, workers: int, max_frames: int | None = None,
                  head_start: int = 0) -> SegmentPlan | None:
    """Cut the clip's frames into up to ``workers`` segments of at least
    :data:`MIN_SEGMENT_FRAMES`; None when fewer than two fit or the clip's frames cannot be
    located without decoding (:func:`~.video.frame_times`).

    The segments of the workers (all but the first) are equal; the first, tracked here
    without a warm-up, gets :data:`WARMUP_FRAMES` more, plus ``head_start`` frames when
    the workers are still starting, so all end at about the same time.
    """
    times = frame_times(clip)
    if times is None:
        return None
    n = len(times.pts) if max_frames is None else min(len(times.pts), int(max_frames))
    k = min(int(workers), n // MIN_SEGMENT_FRAMES)
    if k < 2:
        return None
    length = max(MIN_SEGMENT_FRAMES // 2, (n - WARMUP_FRAMES - head_start) // k)
    first = n - (k - 1) * length
    starts = np.r_[0, first + length * np.arange(k - 1), n].astype(np.int64)
    return SegmentPlan(starts, times)


# ---- the worker processes --------------------------------------------------------------
class SegmentWorkers:
    """``n`` processes, each with a Face Landmarker loaded, waiting for one segment each.

    Start them early (``SegmentWorkers(n, options)``), hand each a job with
    :meth:`submit`, collect with :meth:`result`; :meth:`close` (or the ``with`` block's
    end) stops them, finished or not.

    They are plain ``python -c`` child processes talking pickles over their stdin and
    stdout (not ``multiprocessing``, whose spawned children re-run the caller's main
    script: a notebook's or a script's ``track_clip`` must work without a
    ``__main__`` guard, and a fork would copy this process's threads and GL state).
    """

    def __init__(self, n: int, options: LandmarkerOptions):
        import capture2face

        root = str(Path(capture2face.__file__).resolve().parents[1])
        env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2",
                   PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
        self._procs: list[subprocess.Popen] = []
        self._send: list[Connection] = []
        self._recv: list[Connection] = []
        self._ready = [False] * n
        self._busy: set[int] = set()  # sent a job, no result yet
        self._done: dict[int, tuple] = {}  # results received (kept until asked for)
        try:
            for _ in range(n):
                proc = subprocess.Popen([sys.executable, "-c", _WORKER_CODE], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, env=env, start_new_session=True)
                self._procs.append(proc)
                self._send.append(Connection(os.dup(proc.stdin.fileno()), readable=False))
                self._recv.append(Connection(os.dup(proc.stdout.fileno()), writable=False))
                proc.stdin.close()
                proc.stdout.close()
                # One that died at start-up: its result() says so, and the clip is tracked by one.
                with contextlib.suppress(OSError):
                    self._send[-1].send(options)
        except BaseException:
            self.close()
            raise

    def __len__(self) -> int:
        return len(self._procs)

    def __enter__(self) -> SegmentWorkers:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def ready(self) -> bool:
        """Whether every worker has its landmarker loaded (does not wait)."""
        for i in range(len(self._procs)):
            if not self._ready[i]:
                got = self.poll(i)
                if got is not None:  # an error before the work (kept for result())
                    return False
        return all(self._ready)

    def submit(self, i: int, job: dict) -> None:
        try:
            self._send[i].send(job)
            self._busy.add(i)
        except OSError:
            pass  # the worker is gone: result() says so

    def poll(self, i: int, on_progress=None, timeout: float = 0.0):
        """Worker ``i``'s ``(kind, value)`` once it has sent its result (kept: asking again
        gives it again), else None; progress messages on the way go to
        ``on_progress(frames)``."""
        if i in self._done:
            return self._done[i]
        conn = self._recv[i]
        try:
            while conn.poll(timeout):
                kind, value = conn.recv()
                if kind == "progress":
                    if on_progress is not None:
                        on_progress(value)
                elif kind == "ready":
                    self._ready[i] = True
                else:
                    self._busy.discard(i)
                    self._done[i] = kind, value
                    return kind, value
        except (EOFError, OSError):
            self._done[i] = "error", f"the tracking worker process ended (exit code {self._procs[i].poll()})"
            return self._done[i]
        return None

    def result(self, i: int, on_progress=None):
        """Wait for worker ``i``'s ``(kind, value)``: ("ok", dict) or ("error", message)."""
        while True:
            raise_if_interrupted()
            got = self.poll(i, on_progress, timeout=0.05)
            if got is not None:
                return got

    def close(self) -> None:
        """Stop every worker: idle ones are told to exit, busy ones (an interrupt, a
        fallback) terminated at once."""
        for i, conn in enumerate(self._send):
            if i in self._busy:
                self._procs[i].terminate()
                continue
            with contextlib.suppress(OSError, ValueError):
                conn.send(None)
        self._busy.clear()
        deadline = time.monotonic() + 2.0
        for proc in self._procs:
            try:
                proc.wait(max(0.01, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.terminate()
                try:
                    proc.wait(1.0)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        for conn in self._send + self._recv:
            conn.close()
        self._send, self._recv, self._procs = [], [], []


_WORKER_CODE = "from capture2face.tracking.segments import worker_stdio; worker_stdio()"


def worker_stdio() -> None:
    """A worker process's body (see :class:`SegmentWorkers`): messages on fds 0 and 1,
    anything printed goes to stderr."""
    defer_pyplot()
    out = os.dup(1)
    os.dup2(2, 1)
    send, recv = Connection(out, readable=False), Connection(0, writable=False)
    try:
        options = recv.recv()
    except (EOFError, OSError):
        return
    _worker_main(send, recv, options)


def _worker_main(send, recv, options: LandmarkerOptions) -> None:
    """Load the landmarker, say so, track the one segment it is sent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops its workers on Ctrl-C
    try:
        lm = FaceLandmarker.create_from_options(options)
        lm.prepare()
    except Exception as exc:  # reported to the parent, which falls back
        send.send(("error", f"{exc.__class__.__name__}: {exc}"))
        return
    try:
        send.send(("ready", None))
        job = recv.recv()
        if job is None:
            return
        try:
            send.send(("ok", _track_segment(lm, job, send)))
        except Exception as exc:  # reported to the parent, which falls back
            send.send(("error", f"{exc.__class__.__name__}: {exc}"))
    except (EOFError, OSError):
        pass  # the parent went away
    finally:
        lm.close()


def _box(obs) -> tuple[float, float, float] | None:
    """A face's centre (px) and size (:func:`~capture2face.tracking.landmarker.face_boxes`),
    or None."""
    if obs is None:
        return None
    (centre,), (size,) = face_boxes([obs.landmarks_px])
    return float(centre[0]), float(centre[1]), float(size)


def _track_segment(lm: FaceLandmarker, job: dict, send) -> dict:
    """Track one segment (warm-up first); its landmarks go to a file in ``job["folder"]``
    (the caller puts them in head coordinates, as for its own frames)."""
    k, size = job["k"], tuple(job["size"])
    norm_f = FrameArray(Path(job["folder"]) / f"segment{k}_norm.f32", (N_LANDMARKS, 3), np.float32)
    times: list[float] = []
    warm: list = []
    pending: list = []
    presence: list[np.ndarray] = []
    scores: list[np.ndarray] = []
    n_faces_max = 0
    tail = collections.deque(maxlen=WARMUP_FRAMES)

    def flush() -> None:
        nonlocal n_faces_max, pending
        if pending:
            block = stack_observations(pending)
            pending = []
            norm_f.append(block["norm"])
            presence.append(block["presence"])
            scores.append(block["scores"])
            n_faces_max = max(n_faces_max, int(block["n_faces_max"]))

    try:
        for t, rgb, pts in iter_segment(job["clip"], job["first_pts"], job["stop_pts"], job["rotation"]):
            if (rgb.shape[1], rgb.shape[0]) != size:
                raise CaptureError("frame size changes mid-clip")
            obs = lm.detect(rgb, t)
            if pts < job["start_pts"]:
                warm.append(_box(obs))
                continue
            times.append(t)
            pending.append(obs)
            tail.append(_box(obs))
            if len(pending) >= _FLUSH_FRAMES:
                flush()
            if len(times) % _PROGRESS_EVERY == 0:
                send.send(("progress", _PROGRESS_EVERY))
        flush()
    finally:
        norm_f.close()
    return {"times": np.asarray(times, np.float64), "norm_path": norm_f.path,
            "presence": np.concatenate(presence) if presence else np.zeros(0, bool),
            "scores": np.concatenate(scores) if scores else np.zeros((0, 52)),
            "n_faces_max": max(n_faces_max, lm.n_faces_max), "warm": warm, "tail": list(tail),
            "progress_sent": (len(times) // _PROGRESS_EVERY) * _PROGRESS_EVERY}


def _same_face(before: list, after: list, several_faces: bool) -> bool:
    """Whether two segments follow one face across their cut: ``before`` the previous
    segment's faces on the last warm-up frames, ``after`` the next worker's on the same
    frames (:func:`_box` or None each)."""
    both = [(a, b) for a, b in zip(before, after) if a is not None and b is not None]
    if not both:
        return not several_faces  # one face in the clip: whichever is found is it
    return all(np.hypot(a[0] - b[0], a[1] - b[1]) <= _SAME_FACE * max(a[2], 1.0) for a, b in both)


# ---- the driver ------------------------------------------------------------------------
def track_parallel(clip: str | os.PathLike, info: VideoInfo, options, n_workers: int, new_tracker,
                   progress: bool = True,
                   workdir: str | os.PathLike | None = None, workers: SegmentWorkers | None = None):
    """Track ``clip`` in segments (module doc); None when it is not split (too short, its
    frames cannot be located, ``--face N``) or a stitching check fails: the caller then
    tracks it sequentially.

    Args:
        n_workers: landmarkers at once, this process's included.
        new_tracker: () -> a :class:`~capture2face.tracking.tracker.Tracker` for this
            process's segment, which takes the others' landmarks.
        workers: processes started ahead (:class:`SegmentWorkers`; up to ``n_workers -
            1`` of them are used, and all are closed once the clip is split); None: they
            are started here.
    """
    if options.landmarker.face is not None or n_workers < 2:
        return None
    ready = workers is not None and len(workers) >= 1 and workers.ready()
    plan = plan_segments(clip, min(n_workers, 1 + len(workers)) if workers is not None else n_workers,
                         options.max_frames, head_start=0 if ready else STARTUP_FRAMES)
    if plan is None:
        return None
    k = plan.n_segments
    if workers is None:
        workers = SegmentWorkers(k - 1, options.landmarker)
    scratch = Path(tempfile.mkdtemp(prefix="segments-", dir=os.fspath(workdir) if workdir is not None else None))
    size = (info.width, info.height)
    n = int(plan.starts[-1])
    try:
        for i in range(1, k):
            workers.submit(i - 1, plan.job(i, os.fspath(clip), info.rotation, size, os.fspath(scratch),
                                           options.landmarker.face_model))
        with tqdm(total=n, disable=not progress, unit="frame", desc="tracking", leave=False) as bar:
            tracker = new_tracker()
            try:
                tail = collections.deque(maxlen=WARMUP_FRAMES)
                frames = prefetch(iter_frames(clip, max_frames=int(plan.starts[1])))
                try:
                    for t, rgb in frames:
                        raise_if_interrupted()
                        tail.append(_box(tracker.process(t, rgb)))
                        bar.update(1)
                        for i in range(k - 1):  # the workers' progress, as it comes
                            workers.poll(i, bar.update)
                finally:
                    frames.close()
                if tracker.n_frames != plan.starts[1]:
                    return _fallback(tracker, "the first segment decoded short")
                faces_seen = 0
                for i in range(1, k):
                    kind, value = workers.result(i - 1, bar.update)
                    if kind != "ok":
                        return _fallback(tracker, value)
                    expected = int(plan.starts[i + 1] - plan.starts[i])
                    if len(value["times"]) != expected:
                        return _fallback(tracker, f"segment {i} decoded {len(value['times'])} of {expected} frames")
                    faces_seen = max(faces_seen, tracker.n_faces_max, value["n_faces_max"])
                    several = faces_seen > 1
                    before = list(tail)[-len(value["warm"]):] if value["warm"] else []
                    if not _same_face(before, value["warm"], several):
                        return _fallback(tracker, f"segment {i} started on another face")
                    norm = FrameArray(value["norm_path"], (N_LANDMARKS, 3), np.float32, mode="r")
                    try:
                        tracker.extend(value["times"], norm, value["presence"], value["scores"],
                                       value["n_faces_max"], size)
                    finally:
                        norm.close()
                    tail = collections.deque(value["tail"], maxlen=WARMUP_FRAMES)
                    bar.update(expected - value["progress_sent"])
            except (OSError, EOFError, pickle.PickleError) as exc:  # the workers' pipes, files
                return _fallback(tracker, f"{exc.__class__.__name__}: {exc}")
            except BaseException:
                tracker.close()
                raise
            return tracker.finish(progress)
    finally:
        workers.close()  # each tracks one segment: done, or stopped on a fallback or an error
        shutil.rmtree(scratch, ignore_errors=True)


def _fallback(tracker, why: str) -> None:
    log.debug("segment-parallel tracking not used: %s; tracking sequentially", why)
    tracker.close()
    return None

"""Overlapping frame windows, so that retargeting a long clip holds one window in RAM.

The solve couples frames only through its temporal term, whose reach decays
exponentially (a few dozen frames at the default weights). Each window is solved on its
own with ``overlap`` frames shared with the next one; the result cross-fades linearly over
the middle half of every overlap, where both neighbours are far from their own edges.
Per-frame statistics (the reliability passes' residuals) take each frame from the window
that *owns* it: overlaps are split at their middle.

:class:`MappedPoints` evaluates the RBF network window by window and, when the solve
reads the clip more than once (reliability passes), keeps its output in a temporary raw
file instead of recomputing it (the evaluation costs about as much as the solve).
:class:`SpilledMedian` is the per-feature-point median of the residuals over the whole
clip, exact, with the (F, N) residuals on disk.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass

import numpy as np

from capture2face.io.framestore import FrameArray


@dataclass
class Window:
    """One window of frames.

    Attributes:
        start, stop: the frames solved together (stop exclusive).
        own_start, own_stop: the frames this window owns (a partition of the clip).
        fade: (stop - start,) float64 weight of this window's result per frame; the
            windows' fades sum to 1 on every frame.
    """

    start: int
    stop: int
    own_start: int
    own_stop: int
    fade: np.ndarray

    def pin(self, frame: int | None) -> int | None:
        """``frame`` as an index into this window, None when outside."""
        if frame is None or not self.start <= frame < self.stop:
            return None
        return int(frame) - self.start

    @property
    def own(self) -> slice:
        """The owned frames as a slice into this window's frames."""
        return slice(self.own_start - self.start, self.own_stop - self.start)


def frame_windows(frames: int, window: int, overlap: int) -> list[Window]:
    """Windows of at most ``window`` frames, evenly spaced over ``frames``, neighbours
    sharing at least ``overlap`` frames (all of one length, so the solver's per-length
    factors are shared). A clip no longer than ``window`` is one window.

    A window's weight is 0 within a quarter of the overlap of its inner edges (where the
    solve is least like the whole-clip one), rises linearly to 1 over the next half and
    is normalised by the sum over windows; each frame is owned by its heaviest window.
    """
    window = max(1, int(window))
    overlap = int(min(max(overlap, 0), window - 1))
    if frames <= window:
        return [Window(0, frames, 0, frames, np.ones(frames))]
    count = 1 + int(np.ceil((frames - window) / (window - overlap)))
    # As short as covers the clip with that many windows: no more frames solved than needed.
    window = min(window, int(np.ceil((frames + (count - 1) * overlap) / count)))
    starts = np.round(np.linspace(0, frames - window, count)).astype(int)
    q = max(overlap / 4.0, 0.5)
    frame = np.arange(window) + 0.5
    raw = np.zeros((count, frames))
    for k, s in enumerate(starts):
        edge = np.full(window, np.inf)
        if s > 0:
            edge = np.minimum(edge, frame)
        if s + window < frames:
            edge = np.minimum(edge, window - frame)
        raw[k, s:s + window] = np.clip((edge - q) / (2.0 * q), 1e-12, 1.0)
    fade = raw / raw.sum(0)
    owner = np.argmax(fade, axis=0)
    out = []
    for k, s in enumerate(starts):
        own = np.flatnonzero(owner == k)
        out.append(Window(int(s), int(s + window), int(own[0]), int(own[-1]) + 1, fade[k, s:s + window]))
    return out


class MappedPoints:
    """The RBF network's output (F, N, 3) float64, one window at a time.

    Args:
        source: (F, L, 3) landmarks in head coordinates (an array or a
            :class:`~capture2face.io.framestore.FrameArray`); read by frame ranges.
        network: callable (k, N, 3) -> (k, N, 3), the feature map.
        landmarks: (N,) the landmarks it maps.
        windows: the windows :meth:`read` will be asked for.
        reads: how many times each window will be read (1: nothing is cached).
    """

    def __init__(self, source, network, landmarks: np.ndarray, windows: list[Window], reads: int = 1):
        self.source, self.network, self.landmarks = source, network, np.asarray(landmarks)
        self.windows = windows
        self.frames = windows[-1].stop if windows else 0
        self._dir = None
        self._cache: FrameArray | None = None
        self._single: np.ndarray | None = None
        self._cache_wanted = reads > 1
        self._done = 0  # frames [0, _done) are in the cache

    def _map(self, start: int, stop: int) -> np.ndarray:
        pts = np.asarray(self.source[start:stop], np.float64)[:, self.landmarks]
        return self.network(pts)

    def read(self, w: Window) -> np.ndarray:
        if not self._cache_wanted:
            return self._map(w.start, w.stop)
        if len(self.windows) == 1:  # the whole clip: keep it in RAM
            if self._single is None:
                self._single = self._map(w.start, w.stop)
            return self._single
        if self._cache is None:
            self._dir = tempfile.mkdtemp(prefix="capture2face-retarget-")
            self._cache = FrameArray(os.path.join(self._dir, "mapped.f64"), (len(self.landmarks), 3), np.float64)
        if w.stop > self._done:  # windows come in order; map only what is new
            if w.start > self._done:
                raise ValueError("windows must be read in order the first time")
            self._cache.write(self._done, self._map(self._done, w.stop))
            self._done = w.stop
        return self._cache.read(w.start, w.stop)

    def close(self) -> None:
        self._single = None
        if self._cache is not None:
            self._cache.close()
            self._cache = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def __enter__(self) -> MappedPoints:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SpilledMedian:
    """Per-column median of an (F, N) array that arrives as row blocks (each window's
    owned frames), kept on disk when there is more than one block.

    Blocks are written transposed, (N, k) each, one after the other, so the values of a
    range of columns are one contiguous read per block.
    """

    BLOCK_BYTES = 8 << 20  # values per column range read back at once

    def __init__(self, columns: int):
        self.columns = int(columns)
        self._blocks: list[np.ndarray] = []
        self._records: list[tuple[int, int]] = []  # (offset, rows)
        self._file = None
        self._dir = None
        self._size = 0

    def add(self, rows: np.ndarray) -> None:
        """Append rows (k, N)."""
        rows = np.asarray(rows, np.float64)
        if not self._blocks and self._file is None:
            self._blocks.append(rows)
            return
        if self._file is None:
            self._dir = tempfile.mkdtemp(prefix="capture2face-median-")
            self._file = open(os.path.join(self._dir, "rows.f64"), "w+b")  # noqa: SIM115 - kept open, close() closes it
            for block in self._blocks:
                self._spill(block)
            self._blocks = []
        self._spill(rows)

    def _spill(self, rows: np.ndarray) -> None:
        self._records.append((self._size, rows.shape[0]))
        data = np.ascontiguousarray(rows.T).tobytes()
        self._file.write(data)
        self._size += len(data)

    def median(self) -> np.ndarray:
        """(N,) the median of every column over all rows added."""
        if self._file is None:
            return np.median(self._blocks[0], axis=0) if self._blocks else np.zeros(self.columns)
        self._file.flush()
        fd = self._file.fileno()
        frames = sum(k for _, k in self._records)
        step = max(1, self.BLOCK_BYTES // (8 * max(frames, 1)))
        out = np.empty(self.columns)
        for c0 in range(0, self.columns, step):
            c1 = min(self.columns, c0 + step)
            parts = [np.frombuffer(os.pread(fd, (c1 - c0) * k * 8, off + c0 * k * 8), np.float64).reshape(c1 - c0, k)
                     for off, k in self._records]
            out[c0:c1] = np.median(np.concatenate(parts, axis=1), axis=1)
        return out

    def close(self) -> None:
        self._blocks = []
        if self._file is not None:
            self._file.close()
            self._file = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def __enter__(self) -> SpilledMedian:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""Per-frame arrays kept on disk, so a long clip's landmarks do not live in RAM.

A :class:`FrameArray` is an (F, ...) array stored row by row in a raw file: appended
frame by frame (or block by block) while a clip is tracked, read back window by window.
Reads and writes are plain ``pread``/``pwrite`` calls into freshly allocated arrays, not a
memory map: pages of a map stay mapped (and counted in the process's resident memory) once
touched, so reading a 10-minute clip through one would hold all of it.

The class is array-like enough for the stages that consume a
:class:`~capture2face.tracking.track.Track`: ``len``, ``shape``, ``dtype``, integer and
slice indexing along the frame axis (``a[i]``, ``a[s:e]``, ``a[s:e, idx]``), ``np.asarray``
(reads it all: for short clips and notebooks), and :meth:`FrameArray.iter_chunks` for
streaming writers (:mod:`capture2face.io.npz`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import numpy as np

CHUNK_BYTES = 16 << 20  # what iter_chunks yields at a time (numpy's own npz buffer size)


class FrameArray:
    """(F, *row_shape) array of ``dtype`` in the raw file ``path``, row-major.

    Args:
        path: the file (created, or truncated when ``mode="w"``; opened read-only with
            ``mode="r"``, its length giving F).
        row_shape: shape of one frame's row.
        dtype: element type.
    """

    def __init__(self, path: str | os.PathLike, row_shape: tuple[int, ...], dtype, mode: str = "w"):
        self.path = os.fspath(path)
        self.row_shape = tuple(int(s) for s in row_shape)
        self.dtype = np.dtype(dtype)
        self.row_bytes = int(np.prod(self.row_shape, dtype=np.int64)) * self.dtype.itemsize
        flags = os.O_RDONLY if mode == "r" else os.O_RDWR | os.O_CREAT | os.O_TRUNC
        self._fd = os.open(self.path, flags | getattr(os, "O_CLOEXEC", 0), 0o600)
        self._frames = os.fstat(self._fd).st_size // max(self.row_bytes, 1) if mode == "r" else 0
        self.writable = mode != "r"

    # ---- array protocol -----------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...]:
        return (self._frames,) + self.row_shape

    @property
    def ndim(self) -> int:
        return 1 + len(self.row_shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def __len__(self) -> int:
        return self._frames

    def __repr__(self) -> str:
        return f"FrameArray({self.path!r}, shape={self.shape}, dtype={self.dtype})"

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self.read(0, self._frames)
        return out if dtype is None else out.astype(dtype, copy=False)

    def __getitem__(self, key):
        rest: tuple = ()
        if isinstance(key, tuple):
            key, rest = (key[0], key[1:]) if key else (slice(None), ())
        if isinstance(key, (int, np.integer)):
            i = int(key) + (self._frames if key < 0 else 0)
            if not 0 <= i < self._frames:
                raise IndexError(f"frame {key} out of range for {self._frames} frames")
            return self.read(i, i + 1)[0][rest] if rest else self.read(i, i + 1)[0]
        if isinstance(key, slice):
            start, stop, step = key.indices(self._frames)
            if step == 1:
                out = self.read(start, max(start, stop))
            else:
                lo, hi = (start, stop) if step > 0 else (stop + 1, start + 1)
                out = self.read(lo, max(lo, hi))[start - lo::step] if hi > lo else self.read(0, 0)
            return out[(slice(None),) + rest] if rest else out
        return np.asarray(self)[(key,) + rest]  # masks, index lists: reads everything (short clips)

    # ---- file I/O -------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._fd < 0:
            raise ValueError(f"{self.path}: FrameArray is closed")

    def append(self, rows: np.ndarray) -> None:
        """Add ``rows`` (k, *row_shape) at the end."""
        self.write(self._frames, rows)

    def write(self, start: int, rows: np.ndarray) -> None:
        """Overwrite (or extend) frames ``start .. start + k`` with ``rows`` (k, *row_shape);
        frames skipped over when writing past the end read as zeros until written."""
        self._check_open()
        if not self.writable:
            raise ValueError(f"{self.path}: FrameArray is read-only")
        rows = np.ascontiguousarray(rows, self.dtype).reshape((-1,) + self.row_shape)
        if rows.size == 0:
            return
        view = memoryview(rows).cast("B")
        offset, done = start * self.row_bytes, 0
        while done < len(view):
            done += os.pwrite(self._fd, view[done:], offset + done)
        self._frames = max(self._frames, start + len(rows))

    def read(self, start: int, stop: int) -> np.ndarray:
        """Frames ``start .. stop`` (exclusive) as a new (k, *row_shape) array."""
        self._check_open()
        start, stop = max(0, int(start)), min(self._frames, int(stop))
        out = np.empty((max(0, stop - start),) + self.row_shape, self.dtype)
        if out.size == 0:
            return out
        view = memoryview(out).cast("B")
        offset, done = start * self.row_bytes, 0
        while done < len(view):
            got = os.preadv(self._fd, [view[done:]], offset + done)
            if got <= 0:
                raise OSError(f"{self.path}: short read at frame {start}")
            done += got
        return out

    def read_rows(self, frames: np.ndarray) -> np.ndarray:
        """Arbitrary frames (k,) in the given order (one read per contiguous run)."""
        frames = np.asarray(frames, np.int64)
        out = np.empty((len(frames),) + self.row_shape, self.dtype)
        if len(frames):
            breaks = np.flatnonzero(np.diff(frames) != 1) + 1
            for a, b in zip(np.r_[0, breaks], np.r_[breaks, len(frames)]):
                out[a:b] = self.read(int(frames[a]), int(frames[a]) + (b - a))
        return out

    def iter_chunks(self, chunk_bytes: int = CHUNK_BYTES) -> Iterator[np.ndarray]:
        """The whole array in frame order, a bounded block at a time."""
        rows = max(1, chunk_bytes // max(self.row_bytes, 1))
        for start in range(0, self._frames, rows):
            yield self.read(start, start + rows)

    def reopen_readonly(self) -> FrameArray:
        """A read-only FrameArray of the same file (this one stays open)."""
        out = FrameArray(self.path, self.row_shape, self.dtype, mode="r")
        out._frames = self._frames
        return out

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __del__(self) -> None:
        try:  # noqa: SIM105 - contextlib may already be torn down at interpreter shutdown
            self.close()
        except Exception:  # interpreter shutdown
            pass

    def __getstate__(self):
        raise TypeError("a FrameArray is a view of a run's temporary file; np.asarray() it to pickle")


def take_points(frames, ids, chunk: int = 512) -> np.ndarray:
    """(F, len(ids), ...) float64 ``frames[:, ids]`` of an (F, L, ...) array or
    :class:`FrameArray`, read ``chunk`` frames at a time: of a long clip's disk-backed
    landmarks, only the few points asked for are ever in memory."""
    ids = list(ids)
    n = len(frames)
    out = np.empty((n, len(ids)) + tuple(frames.shape[2:]))
    for s in range(0, n, chunk):
        out[s:s + chunk] = np.asarray(frames[s:s + chunk])[:, ids]
    return out

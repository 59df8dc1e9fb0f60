"""Frames without a face: short gaps are interpolated, long ones hold the last pose.

A gap is a run of frames with no face. Its length is the time it covers: from its first
to its last frame plus one frame period. A gap between two tracked frames that is no
longer than ``max_gap_seconds`` is interpolated in time (linear for landmarks and scores,
slerp for the head rotation). Any other gap - longer, or at the start or end of the clip
where there is nothing on one side - holds the nearest tracked values (the last before it,
or for leading frames the first detected one) and its frames are flagged ``held``.
``n_long_gaps`` counts gaps longer than the limit.

:func:`plan_gaps` says, per frame, where its values come from (``(1 - w) x[lo] + w x[hi]``),
so arrays too big for RAM can be filled window by window (:meth:`GapFill.fill_window`);
:func:`fill_gaps` applies the plan to in-memory arrays and the head pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Slerp

from capture2face.tracking.head_pose import split_pose


@dataclass
class GapFill:
    """What :func:`fill_gaps` did.

    Attributes:
        interpolated: (F,) bool frames filled by interpolation.
        held: (F,) bool frames holding the nearest tracked values.
        n_gaps: runs of frames without a face.
        n_long_gaps: runs longer than the interpolation limit.
        lo, hi: (F,) int64 source frames of each frame's values (both the frame itself
            where a face was found).
        w: (F,) float64 interpolation weight: ``value = (1 - w) x[lo] + w x[hi]``.
    """

    interpolated: np.ndarray
    held: np.ndarray
    n_gaps: int
    n_long_gaps: int
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    w: np.ndarray | None = None

    def fill(self, arr: np.ndarray) -> None:
        """Fill ``arr`` (F, ...) in place (its gap frames' rows are ignored)."""
        gap = np.flatnonzero(self.interpolated | self.held)
        self._blend(arr, gap, arr[self.lo[gap]], arr[self.hi[gap]])

    def fill_window(self, read, start: int, stop: int) -> np.ndarray:
        """Frames ``start .. stop`` of an array, gaps filled.

        Args:
            read: ``read(frames (k,) int64) -> (k, ...)`` rows of the unfilled array.
        Returns:
            (stop - start, ...) float64.
        """
        gap = start + np.flatnonzero(self.interpolated[start:stop] | self.held[start:stop])
        out = np.asarray(read(np.arange(start, stop)), np.float64)
        if gap.size:
            src = np.unique(np.concatenate([self.lo[gap], self.hi[gap]]))
            rows = np.asarray(read(src), np.float64)
            a = rows[np.searchsorted(src, self.lo[gap])]
            b = rows[np.searchsorted(src, self.hi[gap])]
            # Sources inside the window are read again above: identical values.
            self._blend(out, gap - start, a, b, gap)
        return out

    def _blend(self, out: np.ndarray, rows: np.ndarray, a: np.ndarray, b: np.ndarray,
               frames: np.ndarray | None = None) -> None:
        """out[rows] = (1 - w) a + w b for the gap frames ``frames`` (default ``rows``)."""
        if not rows.size:
            return
        w = self.w[rows if frames is None else frames].reshape((-1,) + (1,) * (out.ndim - 1))
        out[rows] = (1.0 - w) * a + w * b


def gap_runs(presence: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs (stop exclusive) of the runs where ``presence`` (F,) is False."""
    missing = np.concatenate([[False], ~np.asarray(presence, bool), [False]])
    edges = np.flatnonzero(np.diff(missing.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def plan_gaps(times: np.ndarray, presence: np.ndarray, max_gap_seconds: float) -> GapFill:
    """Where each frame's values come from (see :class:`GapFill`). At least one frame of
    ``presence`` (F,) must be True."""
    presence = np.asarray(presence, bool)
    n = presence.shape[0]
    interpolated = np.zeros(n, bool)
    held = np.zeros(n, bool)
    lo = np.arange(n, dtype=np.int64)
    hi = lo.copy()
    w = np.zeros(n)
    runs = gap_runs(presence)
    dts = np.diff(times)
    period = float(np.median(dts)) if dts.size else 0.0
    n_long = 0
    for a, b in runs:
        length = float(times[b - 1] - times[a]) + period
        long_gap = length > max_gap_seconds + 1e-9
        n_long += int(long_gap)
        if a > 0 and b < n and not long_gap:
            t0, t1 = times[a - 1], times[b]
            w[a:b] = (times[a:b] - t0) / (t1 - t0)
            lo[a:b], hi[a:b] = a - 1, b
            interpolated[a:b] = True
        else:
            lo[a:b] = hi[a:b] = a - 1 if a > 0 else b  # leading gap: the first detected frame
            held[a:b] = True
    return GapFill(interpolated, held, len(runs), n_long, lo, hi, w)


def fill_pose(gaps: GapFill, pose: np.ndarray) -> None:
    """Fill the gap frames of ``pose`` (F, 4, 4) in place: slerp over short gaps, hold
    over long ones."""
    for a, b in gap_runs(~(gaps.interpolated | gaps.held)):
        if gaps.interpolated[a]:
            trans, rot, scale = split_pose(pose[[a - 1, b]])
            w = gaps.w[a:b]
            r = Slerp([0.0, 1.0], rot)(w)
            s = (1.0 - w) * scale[0] + w * scale[1]
            pose[a:b, :3, :3] = r.as_matrix() * s[:, None, None]
            pose[a:b, :3, 3] = (1.0 - w)[:, None] * trans[0] + w[:, None] * trans[1]
            pose[a:b, 3] = (0.0, 0.0, 0.0, 1.0)
        else:
            pose[a:b] = pose[gaps.lo[a]]


def fill_gaps(times: np.ndarray, presence: np.ndarray, arrays: dict[str, np.ndarray],
              pose: np.ndarray, max_gap_seconds: float) -> GapFill:
    """Fill, in place, the frames of ``arrays`` (each (F, ...)) and ``pose`` (F, 4, 4) where
    ``presence`` (F,) is False. At least one frame must be present."""
    gaps = plan_gaps(times, presence, max_gap_seconds)
    for arr in arrays.values():
        gaps.fill(arr)
    fill_pose(gaps, pose)
    return gaps

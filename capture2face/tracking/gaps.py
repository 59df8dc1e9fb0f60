"""Frames without a face: short gaps are interpolated, long ones hold the last pose.

A gap is a run of frames with no face. Its length is the time it covers: from its first
to its last frame plus one frame period. A gap between two tracked frames that is no
longer than ``max_gap_seconds`` is interpolated in time (linear for landmarks and scores,
slerp for the head rotation). Any other gap - longer, or at the start or end of the clip
where there is nothing on one side - holds the nearest tracked values (the last before it,
or for leading frames the first detected one) and its frames are flagged ``held``.
``n_long_gaps`` counts gaps longer than the limit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


@dataclass
class GapFill:
    """What :func:`fill_gaps` did.

    Attributes:
        interpolated: (F,) bool frames filled by interpolation.
        held: (F,) bool frames holding the nearest tracked values.
        n_gaps: runs of frames without a face.
        n_long_gaps: runs longer than the interpolation limit.
    """

    interpolated: np.ndarray
    held: np.ndarray
    n_gaps: int
    n_long_gaps: int


def gap_runs(presence: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs (stop exclusive) of the runs where ``presence`` (F,) is False."""
    missing = np.concatenate([[False], ~np.asarray(presence, bool), [False]])
    edges = np.flatnonzero(np.diff(missing.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def _split_pose(pose: np.ndarray) -> tuple[np.ndarray, Rotation, np.ndarray]:
    m3 = pose[:, :3, :3]
    scale = np.cbrt(np.linalg.det(m3))
    return pose[:, :3, 3], Rotation.from_matrix(m3 / scale[:, None, None]), scale


def fill_gaps(times: np.ndarray, presence: np.ndarray, arrays: dict[str, np.ndarray],
              pose: np.ndarray, max_gap_seconds: float) -> GapFill:
    """Fill, in place, the frames of ``arrays`` (each (F, ...)) and ``pose`` (F, 4, 4) where
    ``presence`` (F,) is False. At least one frame must be present."""
    presence = np.asarray(presence, bool)
    n = presence.shape[0]
    interpolated = np.zeros(n, bool)
    held = np.zeros(n, bool)
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
            w = (times[a:b] - t0) / (t1 - t0)
            for arr in arrays.values():
                shape = (-1,) + (1,) * (arr.ndim - 1)
                arr[a:b] = (1.0 - w.reshape(shape)) * arr[a - 1] + w.reshape(shape) * arr[b]
            trans, rot, scale = _split_pose(pose[[a - 1, b]])
            r = Slerp([0.0, 1.0], rot)(w)
            s = (1.0 - w) * scale[0] + w * scale[1]
            pose[a:b, :3, :3] = r.as_matrix() * s[:, None, None]
            pose[a:b, :3, 3] = (1.0 - w)[:, None] * trans[0] + w[:, None] * trans[1]
            pose[a:b, 3] = (0.0, 0.0, 0.0, 1.0)
            interpolated[a:b] = True
        else:
            src = a - 1 if a > 0 else b  # leading gap: the first detected frame
            for arr in arrays.values():
                arr[a:b] = arr[src]
            pose[a:b] = pose[src]
            held[a:b] = True
    return GapFill(interpolated, held, len(runs), n_long)

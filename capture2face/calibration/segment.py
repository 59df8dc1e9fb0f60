"""Finding the protocol's steps in a ROM take: runs of motion away from the rest, laid
onto the protocol's order by the tracker's own reading of each."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

# Activity: each landmark group's RMS change over its typical change on the take's idle
# frames, the largest group's, smoothed over SMOOTH_S. Motion is activity above NOISE_RATIO.
NOISE_RATIO = 3.0
SMOOTH_S = 0.1
IDLE_SHARE = 0.2  # the take's calmest frames, whose motion is the tracker's noise
MIN_RUN_S, MERGE_GAP_S = 0.25, 0.12  # shorter runs are dropped; closer ones are one run
# A run's hold: its frames whose activity reaches this share of the run's highest.
HOLD_SHARE = 0.75
# A matched step whose reading looks less like it than this is named in a warning.
MATCH_WARN = 0.2


@dataclass(frozen=True)
class Run:
    """A run of motion: frames ``start..stop-1``, its hold ``hold_start..hold_stop-1``."""

    start: int
    stop: int
    hold_start: int
    hold_stop: int


def idle_frames(motion: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(N,) the valid frames whose largest group motion (F, G), each group over its median,
    is among the :data:`IDLE_SHARE` lowest."""
    frames = np.flatnonzero(valid)
    if not len(frames):
        return frames
    rel = (motion[frames] / np.maximum(np.median(motion[frames], 0), 1e-9)).max(1)
    return frames[rel <= np.quantile(rel, IDLE_SHARE)]


def activity(motion: np.ndarray, idle: np.ndarray, fps: float) -> np.ndarray:
    """(F,) the largest group's motion (F, G) over its median on the ``idle`` frames, smoothed."""
    noise = np.maximum(np.median(motion[idle], 0), 1e-9) if len(idle) else np.maximum(np.median(motion, 0), 1e-9)
    a = (motion / noise).max(1)
    return uniform_filter1d(a, max(1, round(SMOOTH_S * fps)), mode="nearest")


def find_runs(act: np.ndarray, fps: float, valid: np.ndarray) -> list[Run]:
    """Runs of motion in (F,) :func:`activity` ``act``; ``valid`` (F,) frames with a face."""
    moving = (act > NOISE_RATIO) & valid
    edges = np.flatnonzero(np.diff(np.concatenate([[0], moving.astype(np.int8), [0]])))
    spans = [[int(a), int(b)] for a, b in zip(edges[::2], edges[1::2])]
    merged: list[list[int]] = []
    for s in spans:
        if merged and s[0] - merged[-1][1] <= MERGE_GAP_S * fps:
            merged[-1][1] = s[1]
        else:
            merged.append(s)
    runs = []
    for a, b in merged:
        if b - a < MIN_RUN_S * fps:
            continue
        peak = act[a:b].max()
        above = np.flatnonzero(act[a:b] >= HOLD_SHARE * peak)
        runs.append(Run(a, b, a + int(above[0]), a + int(above[-1]) + 1))
    return runs


def align(similarity: np.ndarray) -> list[tuple[int, int]]:
    """Order-keeping match of runs to steps: (run, step) pairs maximizing the sum of
    ``1 + similarity[run, step]`` (R, K), either side free to go unmatched (a step the
    actor left out, a run of motion that is no step)."""
    R, K = similarity.shape
    gain = 1.0 + similarity
    best = np.zeros((R + 1, K + 1))
    for i in range(1, R + 1):
        for k in range(1, K + 1):
            best[i, k] = max(best[i - 1, k], best[i, k - 1], best[i - 1, k - 1] + gain[i - 1, k - 1])
    pairs, i, k = [], R, K
    while i > 0 and k > 0:
        if best[i, k] == best[i - 1, k - 1] + gain[i - 1, k - 1]:
            pairs.append((i - 1, k - 1))
            i, k = i - 1, k - 1
        elif best[i, k] == best[i - 1, k]:
            i -= 1
        else:
            k -= 1
    return pairs[::-1]

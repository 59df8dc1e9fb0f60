"""Finding the protocol's steps in a ROM take: runs of motion away from the rest, laid
onto the protocol's order by the tracker's own reading of each."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import find_peaks

# Activity: each landmark group's RMS change over its typical change on the take's idle
# frames, the largest group's, smoothed over SMOOTH_S. A step is a peak of at least
# MIN_PEAK standing PROMINENCE above its valleys, peaks at least MIN_APART_S apart.
MIN_PEAK, PROMINENCE, MIN_APART_S = 4.0, 2.5, 0.6
RUN_SHARE = 0.4
WEAK_PEAK = 2.0  # a missing step's peak, looked for between its found neighbours
SMOOTH_S = 0.1
IDLE_SHARE = 0.2  # the take's calmest frames, whose motion is the tracker's noise
MIN_RUN_S = 0.25  # shorter runs are dropped
# A run's hold: its frames whose activity reaches this share of the run's highest.
HOLD_SHARE = 0.75
MATCH_BONUS = 0.3
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
    """Runs of motion in (F,) :func:`activity` ``act``: each peak standing
    :data:`PROMINENCE` above the valleys beside it (one per expression: the take returns
    to neutral between steps, though seldom all the way), spanning the frames around it
    above :data:`RUN_SHARE` of it; ``valid`` (F,) frames with a face."""
    act = np.where(valid, act, 0.0)
    peaks, _ = find_peaks(act, height=MIN_PEAK, prominence=PROMINENCE, distance=max(1, round(MIN_APART_S * fps)))
    bounds = np.concatenate([[0], [(a + int(np.argmin(act[a:b]))) for a, b in zip(peaks[:-1], peaks[1:])],
                             [len(act)]])
    runs = []
    for i, p in enumerate(peaks):
        lo, hi = int(bounds[i]), int(bounds[i + 1])
        span = np.flatnonzero(act[lo:hi] >= RUN_SHARE * act[p]) + lo
        hold = np.flatnonzero(act[lo:hi] >= HOLD_SHARE * act[p]) + lo
        start, stop = int(span[0]), int(span[-1]) + 1
        if stop - start >= MIN_RUN_S * fps:
            runs.append(Run(start, stop, int(hold[0]), int(hold[-1]) + 1))
    return runs


def align(similarity: np.ndarray) -> list[tuple[int, int]]:
    """Order-keeping match of runs to steps: (run, step) pairs maximizing the sum of
    ``MATCH_BONUS + similarity[run, step]`` (R, K), either side free to go unmatched (a
    step the actor left out, a run of motion that is no step). The bonus lets the order
    match the steps the tracker cannot read (similarity 0) without letting it pair a run
    with a step it reads unlike when the next step reads like it."""
    R, K = similarity.shape
    gain = MATCH_BONUS + similarity
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


def weak_runs(act: np.ndarray, found: dict[int, Run], n_steps: int, fps: float, valid: np.ndarray) -> dict[int, Run]:
    """Runs for the steps ``found`` (step -> Run) lacks, looked for where the order puts
    them: the frames between the found neighbours, shared evenly among the missing steps
    there, each taking its share's peak when it reaches :data:`WEAK_PEAK` (an expression the
    tracker reads faintly, below the peaks :func:`find_runs` takes)."""
    out: dict[int, Run] = {}
    k = 0
    while k < n_steps:
        if k in found:
            k += 1
            continue
        end = k
        while end < n_steps and end not in found:
            end += 1
        lo = found[k - 1].stop if k - 1 in found else 0
        hi = found[end].start if end in found else len(act)
        while lo + 1 < hi and act[lo + 1] <= act[lo]:  # past the neighbours' own tails
            lo += 1
        while hi - 1 > lo and act[hi - 2] <= act[hi - 1]:
            hi -= 1
        edges = np.linspace(lo, hi, end - k + 1).round().astype(int)
        for j, step in enumerate(range(k, end)):
            a, b = int(edges[j]), int(edges[j + 1])
            if b - a < MIN_RUN_S * fps:
                continue
            part = np.where(valid[a:b], act[a:b], 0.0)
            p = int(np.argmax(part))
            if part[p] < WEAK_PEAK:
                continue
            span = _around(part, p, RUN_SHARE * part[p])
            hold = _around(part, p, HOLD_SHARE * part[p])
            if span[1] - span[0] >= MIN_RUN_S * fps:
                out[step] = Run(a + span[0], a + span[1], a + hold[0], a + hold[1])
        k = end
    return out


def own_hold(run: Run, own: np.ndarray) -> Run:
    """``run`` with its hold found again on ``own`` (F,), the activity of the step's own
    landmark groups only (:func:`activity` of their columns): the longest stretch of the
    run's frames that stays at or above :data:`HOLD_SHARE` of its peak there. A run's hold
    is otherwise where the largest group peaks, which on a run that merges into the next
    step's onset (a frown's return meeting the lids' closing) is the next step's motion;
    and a run that begins with the previous step's return peaks there briefly."""
    part = own[run.start:run.stop]
    if not len(part) or part.max() <= 0.0:
        return run
    high = np.concatenate([[False], part >= HOLD_SHARE * part.max(), [False]])
    edges = np.flatnonzero(np.diff(high.astype(np.int8)))
    starts, stops = edges[::2], edges[1::2]
    j = int(np.argmax(stops - starts))
    return Run(run.start, run.stop, run.start + int(starts[j]), run.start + int(stops[j]))


def _around(values: np.ndarray, peak: int, floor: float) -> tuple[int, int]:
    """(start, stop) of the frames around ``peak`` whose values stay at or above ``floor``."""
    below = values < floor
    left = np.flatnonzero(below[:peak])
    right = np.flatnonzero(below[peak:])
    return (int(left[-1]) + 1 if len(left) else 0), (peak + int(right[0]) if len(right) else len(values))

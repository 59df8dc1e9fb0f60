"""Jitter versus lag of the One Euro filter, measured against synthetic ground truth.

``python -m capture2face.eval.filter_tuning [--frames 150] [--seeds 1 2]`` renders synthetic
clips (or reuses them in ``--dir``), tracks each once, then rebuilds the Track with a grid
of filter settings and prints, per setting, on head-coordinate landmarks (% of the
inter-ocular distance, outer eye corners 33-263):

* **jitter**: frame-to-frame noise of the error against the truth, estimated from its
  second difference (for white noise of deviation s, that has deviation sqrt(6) s);
* **lag**: the time shift (ms) of the truth that best matches the estimate;
* **rms**: the error left after removing each landmark's constant offset (shape bias).

The head pose is measured the same way on the canonical face carried by the estimated and
by the true pose (camera space), which turns rotation and translation errors into surface
motion in the same units.

The TrackOptions defaults were chosen from this table.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from capture2face.io.video_input import iter_frames, open_video
from capture2face.synth import SyntheticTruth, SynthOptions, synthesize, truth_path
from capture2face.topology import IOD_PAIR
from capture2face.tracking import TrackOptions, build_track
from capture2face.tracking.head_pose import canonical_mesh
from capture2face.tracking.landmarker import FaceLandmarker

EYE_CORNERS = IOD_PAIR


def iod(points: np.ndarray) -> float:
    """Median inter-ocular distance (outer eye corners) of (F, L, D) points."""
    return float(np.nanmedian(np.linalg.norm(points[:, EYE_CORNERS[0]] - points[:, EYE_CORNERS[1]], axis=-1)))


def jitter_lag(estimate: np.ndarray, truth: np.ndarray, times: np.ndarray,
               max_lag: float = 0.2) -> dict:
    """Jitter, lag and bias-free RMS error of ``estimate`` against ``truth`` (F, L, 3).

    Landmarks with NaN truth are ignored. Figures in % of the truth's IOD; lag in ms.
    """
    keep = np.isfinite(truth).all(axis=(0, 2))
    est, tru = estimate[:, keep].astype(np.float64), truth[:, keep].astype(np.float64)
    scale = 100.0 / iod(truth)
    err = est - tru
    err -= err.mean(0)
    d2 = err[2:] - 2.0 * err[1:-1] + err[:-2]
    jitter = float(np.sqrt((d2 ** 2).sum(-1).mean() / 6.0)) * scale
    shifts = np.arange(-max_lag, max_lag + 1e-9, 0.004)
    inner = (times >= times[0] + max_lag) & (times <= times[-1] - max_lag)
    flat = tru.reshape(len(times), -1)
    costs = []
    for s in shifts:
        tq = times[inner] - s
        hi = np.clip(np.searchsorted(times, tq), 1, len(times) - 1)
        w = ((tq - times[hi - 1]) / (times[hi] - times[hi - 1]))[:, None]
        shifted = (1.0 - w) * flat[hi - 1] + w * flat[hi]
        e = est[inner].reshape(inner.sum(), -1) - shifted
        e -= e.mean(0)
        costs.append((e ** 2).mean())
    lag = float(shifts[int(np.argmin(costs))]) * 1000.0
    rms = float(np.sqrt((err ** 2).sum(-1).mean())) * scale
    return {"jitter": jitter, "lag_ms": lag, "rms": rms}


def observe(clip: str | Path, options: TrackOptions | None = None):
    """Track ``clip`` once; returns what :func:`build_track` needs to rebuild it cheaply."""
    info = open_video(clip)
    times, obs, size = [], [], (info.width, info.height)
    # Detection only: build_track does the head coordinates, gaps and filtering later.
    with FaceLandmarker.create_from_options((options or TrackOptions()).landmarker) as landmarker:
        for t, rgb in iter_frames(clip):
            times.append(t)
            obs.append(landmarker.detect(rgb, t))
            size = (rgb.shape[1], rgb.shape[0])
    return times, obs, size, info


def posed_face(pose: np.ndarray) -> np.ndarray:
    """(F, 468, 3) the canonical face carried into camera space by ``pose`` (F, 4, 4)."""
    verts = canonical_mesh().vertices.astype(np.float64)
    pose = np.asarray(pose, np.float64)
    return np.einsum("fij,nj->fni", pose[:, :3, :3], verts) + pose[:, None, :3, 3]


def sweep(observations, truths, grid: dict, target: str = "landmarks") -> list[dict]:
    """Mean figures over clips for every combination in ``grid`` (TrackOptions fields);
    ``target`` "landmarks" (head coordinates) or "pose"."""
    rows = []
    keys = list(grid)
    for values in itertools.product(*(grid[k] for k in keys)):
        opts = replace(TrackOptions(), **dict(zip(keys, values)))
        figs = []
        for (times, obs, size, info), truth in zip(observations, truths):
            track = build_track(times, obs, size, info, opts)
            if target == "pose":
                figs.append(jitter_lag(posed_face(track.head_pose), posed_face(truth.head_pose), track.times))
            else:
                figs.append(jitter_lag(track.landmarks_head, truth.landmarks_head, track.times))
        row = dict(zip(keys, values))
        row.update({k: float(np.mean([f[k] for f in figs])) for k in figs[0]})
        rows.append(row)
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cache = Path(os.environ.get("CAPTURE2FACE_CACHE", Path.home() / ".cache" / "capture2face"))
    ap.add_argument("--dir", default=str(cache / "synth_tuning"), help="where the synthetic clips live")
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--json", help="write the table here")
    args = ap.parse_args(argv)
    observations, truths = [], []
    for seed in args.seeds:
        clip = Path(args.dir) / f"seed{seed}_{args.frames}.mp4"
        if not clip.exists() or not Path(truth_path(clip)).exists():
            synthesize(clip, SynthOptions(frames=args.frames, seed=seed))
        truths.append(SyntheticTruth.load(truth_path(clip)))
        observations.append(observe(clip))
        print(f"tracked {clip}", flush=True)
    inf = float("inf")
    rows = sweep(observations, truths, {"min_cutoff": [inf]})  # unfiltered reference
    rows += sweep(observations, truths, {
        "zero_phase": [False, True], "min_cutoff": [0.5, 1.0, 2.0, 4.0], "beta": [0.0, 0.2, 0.5, 2.0],
    })
    pose_rows = sweep(observations, truths, {"pose_min_cutoff": [inf]}, "pose")
    pose_rows += sweep(observations, truths, {
        "zero_phase": [False, True], "pose_min_cutoff": [0.5, 1.0, 2.0, 4.0], "pose_beta": [0.0, 0.2, 0.5, 2.0],
    }, "pose")
    for title, table, mc, b in (("head-coordinate landmarks", rows, "min_cutoff", "beta"),
                                ("head pose", pose_rows, "pose_min_cutoff", "pose_beta")):
        print(f"\n{title}\n{'zero_phase':>10} {'min_cutoff':>10} {'beta':>6} {'jitter%':>8} {'lag_ms':>7} {'rms%':>6}")
        for r in table:
            print(f"{str(r.get('zero_phase', '-')):>10} {r[mc]:>10.2f} {r.get(b, 0):>6.2f} "
                  f"{r['jitter']:>8.3f} {r['lag_ms']:>7.0f} {r['rms']:>6.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"landmarks": rows, "pose": pose_rows}, indent=1))


if __name__ == "__main__":
    main()

"""How far MediaPipe's reading can carry a calibration (docs/calibration.md "The ceiling").

    python tools/calibration_bound.py --takes ROM.track.npz ... --performances PERF.track.npz ...
        [--json OUT]

A calibration learns, from one range-of-motion take, a map from what the tracker reads of a
frame to each ARKit curve, without knowing the take's true curves. This tool gives such a
map every advantage instead: for each performance of one actor, a ridge map from the same
reading (the calibration's features of the curve's own region, against the clip's own rest,
and the head's pose terms) to each goal curve is fitted on the *true* curves of every take
of that actor and of its other performances, and judged on the held-out performance, with
the ridge's strength picked on that performance's truth. Two fits: on the takes alone (what
a take could teach if every frame were labelled) and on the takes and the other
performances. Where even these miss a goal, no map learned from a take reaches it from
this reading.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from calibration_across_takes import GOALS, R_GOAL, load_performance, stem, take_arguments

RIDGES = (1e-4, 1e-3, 1e-2, 1e-1)
# The radial-basis fit (Dutreve's retargeting is an RBF network): kernel widths as shares of
# the fitted frames' median squared distance, and the ridge on the kernel's diagonal.
RBF_WIDTHS, RBF_RIDGES = (1.0, 4.0, 16.0, 64.0), (0.01, 0.1, 1.0, 10.0, 100.0)


def reading(track) -> tuple[np.ndarray, np.ndarray]:
    """(F, D) the calibration's features of every frame against the track's own rest frame,
    and (F, 13) the head's pose terms."""
    from capture2face.calibration.features import frame_features, pose_terms

    nf = track.neutral_frame
    features = frame_features(track.landmarks_head, track.blendshapes, np.asarray(track.landmarks_head[nf], np.float64),
                              np.asarray(track.blendshapes[nf], np.float64), np.arange(len(track.blendshape_names)))
    return features, pose_terms(track.head_pose)


def ridge_predict(x_fit: np.ndarray, y_fit: np.ndarray, x_new: np.ndarray, ridge: float) -> np.ndarray:
    """(N,) a ridge map fitted on (F, D) ``x_fit`` -> (F,) ``y_fit``, on standardized
    columns (``ridge`` times the frame count on each), applied to (N, D) ``x_new``."""
    mu, sd = x_fit.mean(0), x_fit.std(0) + 1e-9
    a = (x_fit - mu) / sd
    w = np.linalg.solve(a.T @ a + ridge * len(a) * np.eye(a.shape[1]), a.T @ (y_fit - y_fit.mean()))
    return ((x_new - mu) / sd) @ w + y_fit.mean()


def rbf_predicts(x_fit: np.ndarray, y_fit: np.ndarray, x_new: np.ndarray):
    """Yield ((N,) prediction, (width, ridge)) of a Gaussian-kernel ridge map fitted on (F, D)
    ``x_fit`` -> (F,) ``y_fit`` (standardized columns), for each of :data:`RBF_WIDTHS` x
    :data:`RBF_RIDGES`, applied to (N, D) ``x_new``."""
    from scipy.linalg import solve

    mu, sd = x_fit.mean(0), x_fit.std(0) + 1e-9
    a, b = (x_fit - mu) / sd, (x_new - mu) / sd
    sq_a, sq_b = (a * a).sum(1), (b * b).sum(1)
    d_fit = np.maximum(sq_a[:, None] + sq_a[None] - 2.0 * a @ a.T, 0.0)
    d_new = np.maximum(sq_b[:, None] + sq_a[None] - 2.0 * b @ a.T, 0.0)
    scale = float(np.median(d_fit))
    for width in RBF_WIDTHS:
        k_fit, k_new = np.exp(-d_fit / (width * scale)), np.exp(-d_new / (width * scale))
        for ridge in RBF_RIDGES:
            alpha = solve(k_fit + ridge * np.eye(len(k_fit)), y_fit - y_fit.mean(), assume_a="pos")
            yield k_new @ alpha + y_fit.mean(), (width, ridge)


def best_fit(x_fit, y_fit, x_new, y_new, kind: str = "ridge") -> tuple[float, float, object]:
    """(r, MAE, setting) of the best setting (:data:`RIDGES`, or for ``kind`` "rbf"
    :func:`rbf_predicts`'s) on the held-out truth ``y_new``."""
    from capture2face.maths.stats import pearson

    if kind == "rbf":
        predicts = rbf_predicts(x_fit, y_fit, x_new)
    else:
        predicts = ((ridge_predict(x_fit, y_fit, x_new, ridge), ridge) for ridge in RIDGES)
    fits = [(float(pearson(pred, y_new)), float(np.abs(np.clip(pred, 0, 1) - y_new).mean()), setting)
            for pred, setting in predicts]
    return max(fits, key=lambda f: f[0])


FITS = ("takes ridge", "takes rbf", "takes+others ridge", "takes+others rbf")


def bound_figures(takes: list[Path], performances: list[Path]) -> dict:
    """{PERF: {curve: {"mediapipe": [r, MAE], FIT: [r, MAE, setting] for FIT in :data:`FITS`}}}
    (the "takes+others" fits only where the actor has another performance)."""
    from capture2face.calibration.features import curve_mask
    from capture2face.eval.synthetic import arkit_columns
    from capture2face.maths.stats import pearson

    def labelled(path: Path):
        track, truth = load_performance(path)
        features, pose = reading(track)
        cols = arkit_columns(truth.blend_names)
        return track, features, pose, {c: truth.blend_weights[:, cols[c]].astype(np.float64) for c in GOALS}

    take_data = [labelled(p) for p in takes]
    perf_data = {stem(p): labelled(p) for p in performances}
    out = {}
    for name, (track, features, pose, truth) in perf_data.items():
        others = [d for n, d in perf_data.items() if n != name]
        names = list(track.blendshape_names)
        row = {}
        for curve in GOALS:
            mask = curve_mask([curve], names, np.arange(len(names)))
            x_new, y_new = np.concatenate([features[:, mask], pose], 1), truth[curve]
            raw = track.blendshapes[:, names.index(curve)].astype(np.float64)
            row[curve] = {"mediapipe": [round(float(pearson(raw, y_new)), 3),
                                        round(float(np.abs(raw - y_new).mean()), 4)]}
            for fit in FITS:
                data = take_data + others if fit.startswith("takes+others") else take_data
                if fit.startswith("takes+others") and not others:
                    continue
                x_fit = np.concatenate([np.concatenate([f[:, mask], p], 1) for _, f, p, _ in data])
                y_fit = np.concatenate([t[curve] for *_, t in data])
                r, mae, setting = best_fit(x_fit, y_fit, x_new, y_new, fit.split()[1])
                row[curve][fit] = [round(r, 3), round(mae, 4), setting]
        out[name] = row
    return out


def table(figures: dict) -> str:
    """Markdown: per performance and goal curve, MediaPipe's r / MAE and each fit's (bold:
    the goal met, r >= 0.9 and MAE below MediaPipe's)."""
    lines = ["| performance | fit | " + " | ".join(GOALS) + " |", "|---|---|" + "---|" * len(GOALS)]
    for perf, row in figures.items():
        for fit in ("mediapipe", *FITS):
            if fit not in row[GOALS[0]]:
                continue
            cells = []
            for c in GOALS:
                r, mae = row[c][fit][:2]
                met = fit != "mediapipe" and r >= R_GOAL and mae < row[c]["mediapipe"][1]
                cells.append(f"**{r:.2f} / {mae:.3f}**" if met else f"{r:.2f} / {mae:.3f}")
            lines.append(f"| {perf} | {fit} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    take_arguments(parser)
    parser.add_argument("--json", type=Path, default=None, help="write every performance's figures")
    args = parser.parse_args(argv)
    figures = bound_figures(args.takes, args.performances)
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1))
    print(table(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

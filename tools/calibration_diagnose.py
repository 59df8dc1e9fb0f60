"""Why a calibrated curve misses its truth (docs/calibration.md "Round five: jawOpen").

    python tools/calibration_diagnose.py --takes ROM.track.npz ... --performances PERF.track.npz ...
        [--curve jawOpen] [--uncalibrated] [--top 4] [--frames 4] [--json OUT]

Takes and performances as ``tools/calibration_across_takes.py``'s. Per (performance, take), the
``--curve`` (calibrated by the take; ``--uncalibrated``: the tracker's, as read) against the
truth: r, its line's gain, the best cubic's r, the lag (frames late) with the best r, r less
the head's pose terms fitted beside the truth on each performance (its own: in-sample), its
error's r with the truth curves (``--top``), MediaPipe's score's r, the worst frames a second
apart; the take's curve and score at each step's hold, and the rows most like the curve's
step's (cosine). For jawOpen also the chin's drop (IOD, the take's pose model off): r with the
truth jaw, IOD per unit here and at the take's hold, its error's r with the truths and pitch.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from calibration_across_takes import load_performance, stem, take_arguments

LAGS = range(-4, 5)
ACTIVE = 0.05  # truth curves that never reach this are left out of the error's correlations


def _r(a, b) -> float:
    from capture2face.maths.stats import pearson
    return round(pearson(a, b), 3)


def curve_figures(curve: np.ndarray, truth: np.ndarray, others: dict[str, np.ndarray], top: int = 4) -> dict:
    """The curve (F,) against its truth (F,): r, line gain, cubic r, best lag, and the r of its
    error off the line with each of ``others`` (name -> (F,) truth curve), highest first."""
    gain, offset = np.polyfit(truth, curve, 1)
    lags = {s: _r(curve[s:], truth[:len(truth) - s]) if s >= 0 else _r(curve[:s], truth[-s:]) for s in LAGS}
    best = max(lags, key=lags.get)
    error = curve - (gain * truth + offset)
    return {"r": _r(curve, truth), "gain": round(float(gain), 3),
            "cubic_r": _r(np.polyval(np.polyfit(truth, curve, 3), truth), curve),
            "lag": best, "lag_r": lags[best], "error_r": error_correlations(error, others, top)}


def error_correlations(error: np.ndarray, others: dict[str, np.ndarray], top: int) -> dict[str, float]:
    """The ``top`` truth curves (of those that move) the error follows most, by |r|."""
    corr = sorted(((k, _r(error, v)) for k, v in others.items() if v.max() > ACTIVE), key=lambda kv: -abs(kv[1]))
    return dict(corr[:top])


def worst_frames(curve, truth, score, others: dict, fps: float, count: int) -> list[dict]:
    """The ``count`` frames where the curve is furthest from the truth, a second apart."""
    out: list[int] = []  # greedy: the worst first, then the worst a second from those
    for f in np.argsort(-np.abs(curve - truth)):
        if len(out) < count and all(abs(int(f) - g) >= fps for g in out):
            out.append(int(f))
    return [{"frame": f, "curve": round(float(curve[f]), 2), "truth": round(float(truth[f]), 2),
             "score": round(float(score[f]), 2),
             "active": dict(sorted(((k, round(float(v[f]), 2)) for k, v in others.items() if v[f] > 0.2),
                                   key=lambda kv: -kv[1])[:5])} for f in sorted(out)]


def chin_drop(track, calibration, aligned: bool = True) -> np.ndarray:
    """(F,) the chin landmarks' mean drop from the calibration's rest (IOD), the pose model's shift off."""
    from capture2face.calibration.features import LANDMARKS, frame_features, pose_terms
    from capture2face.calibration.learn import calibration_rest
    from capture2face.topology import CHIN

    rest = calibration_rest(calibration, track if aligned else None)
    cols = np.array([i for i, n in enumerate(calibration.score_names) if n != "_neutral"])
    feats = frame_features(track.landmarks_head, track.blendshapes, rest.landmarks, rest.scores, cols)
    feats -= pose_terms(np.asarray(track.head_pose)) @ calibration.pose_model
    rows = [3 * int(np.flatnonzero(c == LANDMARKS)[0]) + 1 for c in CHIN]
    return -feats[:, rows].mean(1)


def take_figures(rom, calibration, base: np.ndarray, curve: str) -> tuple[dict, str | None]:
    """Each found step's hold: (the curve, MediaPipe's score); the step showing the curve most."""
    from capture2face.calibration.protocol import PROTOCOL

    c = list(rom.blendshape_names).index(curve)
    holds = {f.name: [round(float(base[f.hold[0]:f.hold[1] + 1, c].mean()), 2),
                      round(float(np.nanmean(rom.blendshapes[f.hold[0]:f.hold[1] + 1, c])), 2)]
             for f in calibration.steps if f.found}
    shown = {s.name: s.targets.get(curve, 0.0) for s in PROTOCOL if s.name in holds}
    step = max(shown, key=shown.get) if shown and max(shown.values()) > 0 else None
    return {k: v for k, v in holds.items() if max(v) >= 0.05}, step


def row_cosines(calibration, step: str, top: int) -> dict:
    """The ``top`` other basis rows most like ``step``'s (cosine)."""
    basis, names = np.asarray(calibration.basis), list(calibration.basis_steps)
    if step not in names:
        return {}
    row = basis[names.index(step)]
    cos = basis @ row / np.maximum(np.linalg.norm(basis, axis=1) * np.linalg.norm(row), 1e-12)
    return {names[k]: round(float(cos[k]), 2) for k in [k for k in np.argsort(-cos) if names[k] != step][:top]}


def pair_figures(take: Path, performances: list[Path], curve: str, calibrated: bool, top: int, frames: int) -> dict:
    """{"PERF|TAKE": figures} for one take and every performance."""
    from capture2face.calibration import calibrate
    from capture2face.calibration.attach import attach
    from capture2face.calibration.features import pose_terms
    from capture2face.eval.synthetic import arkit_columns
    from capture2face.retarget.arkit import arkit_curves
    from capture2face.tracking.track import Track

    rom = Track.load(take)
    base = arkit_curves(rom)
    cal = calibrate(rom, base_curves=base)
    holds, step = take_figures(rom, cal, base, curve)
    out, series = {}, {}
    for p in performances:
        track, truth = load_performance(p)
        tr = {n: truth.blend_weights[:, k].astype(np.float64) for n, k in arkit_columns(truth.blend_names).items()}
        c = list(track.blendshape_names).index(curve)
        read = arkit_curves(attach(track, cal) if calibrated else track)[:, c].astype(np.float64)
        score = np.nan_to_num(track.blendshapes[:, c].astype(np.float64))
        others = {k: v for k, v in tr.items() if k != curve}
        fig = curve_figures(read, tr[curve], others, top)
        fig.update(score_r=_r(score, tr[curve]), worst=worst_frames(read, tr[curve], score, others, track.fps, frames),
                   take_holds=holds, rows_like=step and {step: row_cosines(cal, step, top)})
        pose = pose_terms(np.asarray(track.head_pose))
        if curve == "jawOpen" and step:
            fig["chin"] = _chin(track, rom, cal, step, tr, pose, top)
        series[stem(p)] = (read, tr[curve], pose)
        out[f"{stem(p)}|{stem(take)}"] = fig
    for name, fits in pose_fits(series).items():
        out[f"{name}|{stem(take)}"]["pose_fit_r"] = fits
    return out


def pose_fits(series: dict) -> dict:
    """name -> {fitted on: r}: the curve less the pose terms fitted beside the truth on each performance."""
    fits = {k: np.linalg.lstsq(np.c_[t, P], c, rcond=None)[0] for k, (c, t, P) in series.items()}
    return {k: {f: _r(c - P[:, :-1] @ b[1:-1], t) for f, b in fits.items()} for k, (c, t, P) in series.items()}


def _chin(track, rom, calibration, step: str, truth: dict, pose: np.ndarray, top: int) -> dict:
    """The chin's drop against the truth jaw; its gain per unit of jaw here and at the take's hold."""
    from capture2face.calibration.protocol import PROTOCOL

    drop, jaw = chin_drop(track, calibration), truth["jawOpen"]
    gain, offset = np.polyfit(jaw, drop, 1)
    error = drop - (gain * jaw + offset)
    fit = next(f for f in calibration.steps if f.name == step)
    target = next(s for s in PROTOCOL if s.name == step).targets["jawOpen"]
    at_hold = chin_drop(rom, calibration, aligned=False)[fit.hold[0]:fit.hold[1] + 1].mean() / target
    return {"r": _r(drop, jaw), "gain": round(float(gain), 3), "take_gain": round(float(at_hold), 3),
            "error_r": error_correlations(error, {k: v for k, v in truth.items() if k != "jawOpen"}, top),
            "error_pitch_r": _r(error, pose[:, 0])}


def report(key: str, f: dict) -> str:
    """One pair's figures as a few lines of text."""
    lines = [f"{key}: r {f['r']:.3f}, line gain {f['gain']:.2f}, cubic r {f['cubic_r']:.3f}, "
             f"best lag {f['lag']:+d} (r {f['lag_r']:.3f}), MediaPipe's score r {f['score_r']:.3f}",
             "  error r with truth: " + ", ".join(f"{k} {v:+.2f}" for k, v in f["error_r"].items()),
             "  less the pose terms fitted on: " + ", ".join(f"{k} {v:.3f}" for k, v in f["pose_fit_r"].items())]
    if "chin" in f:
        ch = f["chin"]
        lines.append(f"  chin drop r {ch['r']:.3f}, {ch['gain']:.3f} IOD per unit (take's hold {ch['take_gain']:.3f}); "
                     "its error r: " + ", ".join(f"{k} {v:+.2f}" for k, v in ch["error_r"].items())
                     + f", pitch {ch['error_pitch_r']:+.2f}")
    lines += [f"  frame {w['frame']}: curve {w['curve']:.2f} truth {w['truth']:.2f} score {w['score']:.2f} "
              + " ".join(f"{k} {v:.2f}" for k, v in w["active"].items()) for w in f["worst"]]
    lines.append("  holds (curve/score): " + ", ".join(f"{k} {a:.2f}/{b:.2f}" for k, (a, b) in f["take_holds"].items()))
    for step, cos in (f["rows_like"] or {}).items():
        lines.append(f"  rows like {step}'s (cosine): " + ", ".join(f"{k} {v:.2f}" for k, v in cos.items()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    take_arguments(parser)
    parser.add_argument("--curve", default="jawOpen", help="the ARKit curve to diagnose (jawOpen, eyeBlinkLeft, ...)")
    parser.add_argument("--uncalibrated", action="store_true", help="the tracker's curve as read, not the calibrated")
    parser.add_argument("--top", type=int, default=4, help="how many correlations and rows to list")
    parser.add_argument("--frames", type=int, default=4, help="how many worst frames to list")
    parser.add_argument("--json", type=Path, default=None, help="write every pair's figures")
    args = parser.parse_args(argv)
    out = {k: v for take in args.takes
           for k, v in pair_figures(take, args.performances, args.curve, not args.uncalibrated, args.top,
                                    args.frames).items()}
    for key in sorted(out):
        print(report(key, out[key]))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How much a calibration depends on its take (docs/calibration.md "Across takes").

    python tools/calibration_across_takes.py --takes ROM.track.npz ... --performances PERF.track.npz ...
        [--json OUT] [--before EARLIER.json]

Every take (a tracked range-of-motion take of one actor: ``capture2face synth --rom --actor
A --seed S -o ROM.mp4`` then ``capture2face track ROM.mp4 -o ROM.track.npz``) calibrates,
and every performance of that actor (a tracked ``capture2face synth --actor A`` render, its
truth beside it as ``PERF.truth.npz``) is read with each calibration. For each performance
and each of the issue's goal curves: ``mean r [lowest, highest] / mean MAE`` over the
takes, and how many (take, curve) pairs meet the goal (r >= 0.9, MAE below MediaPipe's raw
score). ``--json`` keeps every pair's figures; ``--before`` prints an earlier run's JSON
(of the same takes and performances) beside this one's as ``before -> after``.
``--together``: also every performance read with all the takes calibrating together
(``capture2face calibrate TAKE TAKE ...``: the mean of each take's curves), a row of its own.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

GOALS = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp", "browDownLeft", "browDownRight",
         "mouthSmileLeft", "mouthSmileRight")
R_GOAL = 0.9


def take_arguments(parser: argparse.ArgumentParser) -> None:
    """``--takes`` and ``--performances``, as every calibration tool takes them."""
    parser.add_argument("--takes", nargs="+", type=Path, required=True, help="tracked ROM takes of one actor")
    parser.add_argument("--performances", nargs="+", type=Path, required=True,
                        help="tracked synthetic performances of that actor (PERF.truth.npz beside each)")


def stem(path: Path) -> str:
    """A tracked take's or performance's name: its file name less ``.track.npz``."""
    return path.name.replace(".track.npz", "")


def load_performance(path: Path):
    """(Track, SyntheticTruth) of a tracked performance, its truth beside it."""
    from capture2face.synth.truth import SyntheticTruth
    from capture2face.tracking.track import Track

    return Track.load(path), SyntheticTruth.load(str(path).replace(".track.npz", ".truth.npz"))


TOGETHER = "together"  # the key (PERF|together) of the takes calibrating together


def pair_figures(takes: list[Path], performances: list[Path], together: bool = False) -> dict:
    """{"PERF|TAKE": {curve: [r, MAE, MediaPipe's MAE]}} for every take and performance (and
    with ``together``, "PERF|together" for all the takes calibrating together)."""
    from capture2face.calibration import ActorCalibration, calibrate
    from capture2face.calibration.attach import attach
    from capture2face.eval.synthetic import arkit_columns
    from capture2face.maths.stats import pearson
    from capture2face.retarget.arkit import arkit_curves
    from capture2face.tracking.track import Track

    perfs = {stem(p): load_performance(p) for p in performances}
    calibrations = {}
    for take in takes:
        rom = Track.load(take)
        calibrations[stem(take)] = calibrate(rom, base_curves=arkit_curves(rom))
    if together:
        calibrations[TOGETHER] = ActorCalibration.together(list(calibrations.values()))
    out = {}
    for take, calibration in calibrations.items():
        for name, (track, truth) in perfs.items():
            curves = arkit_curves(attach(track, calibration))
            cols, truth_cols = list(track.blendshape_names), arkit_columns(truth.blend_names)
            row = {}
            for curve in GOALS:
                c, true = cols.index(curve), truth.blend_weights[:, truth_cols[curve]].astype(np.float64)
                raw = track.blendshapes[:, c].astype(np.float64)
                row[curve] = [round(float(pearson(curves[:, c], true)), 3),
                              round(float(np.abs(curves[:, c] - true).mean()), 4),
                              round(float(np.abs(raw - true).mean()), 4)]
            out[f"{name}|{take}"] = row
    return out


def met(row: dict) -> int:
    return sum(r >= R_GOAL and mae < raw for r, mae, raw in row.values())


def _cell(d: dict, keys: list[str], curve: str) -> str:
    rs = np.array([d[k][curve][0] for k in keys])
    return f"{rs.mean():.2f} [{rs.min():.2f}, {rs.max():.2f}] / {np.mean([d[k][curve][1] for k in keys]):.3f}"


def table(after: dict, before: dict | None = None) -> str:
    """Markdown: per performance, each goal curve over its takes, and the goals met; below
    it, the takes calibrating together where measured."""
    lines = ["| performance (takes) | " + " | ".join(GOALS) + " | goals met |", "|---|" + "---|" * (len(GOALS) + 1)]
    for perf in sorted({k.split("|")[0] for k in after}):
        keys = sorted(k for k in after if k.startswith(perf + "|") and k != f"{perf}|{TOGETHER}")
        cells = [(f"{_cell(before, keys, c)} -> " if before else "") + _cell(after, keys, c) for c in GOALS]
        count = sum(met(after[k]) for k in keys)
        goals = (f"{sum(met(before[k]) for k in keys)} -> " if before else "") + f"{count} of {len(GOALS) * len(keys)}"
        takes = ", ".join(k.split("|")[1] for k in keys)
        lines.append(f"| {perf} ({takes}) | " + " | ".join(cells) + f" | {goals} |")
        row = after.get(f"{perf}|{TOGETHER}")
        if row:
            was = (before or {}).get(f"{perf}|{TOGETHER}")
            cells = [(f"{was[c][0]:.2f} / {was[c][1]:.3f} -> " if was else "") + f"{row[c][0]:.2f} / {row[c][1]:.3f}"
                     for c in GOALS]
            goals = (f"{met(was)} -> " if was else "") + f"{met(row)} of {len(GOALS)}"
            lines.append(f"| {perf} (all {len(keys)} together) | " + " | ".join(cells) + f" | {goals} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    take_arguments(parser)
    parser.add_argument("--json", type=Path, default=None, help="write every (performance, take) pair's figures")
    parser.add_argument("--before", type=Path, default=None, help="an earlier --json of the same takes, shown beside")
    parser.add_argument("--together", action="store_true", help="also all the takes calibrating together")
    args = parser.parse_args(argv)
    after = pair_figures(args.takes, args.performances, args.together)
    if args.json:
        args.json.write_text(json.dumps(after, indent=1))
    before = json.loads(args.before.read_text()) if args.before else None
    print(table(after, before))
    single = [row for key, row in after.items() if not key.endswith(f"|{TOGETHER}")]
    print(f"goals met: {sum(met(row) for row in single)} of {len(GOALS) * len(single)}")
    joint = [row for key, row in after.items() if key.endswith(f"|{TOGETHER}")]
    if joint:
        print(f"goals met with the takes together: {sum(met(row) for row in joint)} of {len(GOALS) * len(joint)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

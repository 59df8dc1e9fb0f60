"""The renderer of this tree against an earlier commit's, in one process, round by round.

    python tools/render_vs_commit.py f0965a6 [--rounds 12] [--frames 40] [--size 512]

Separate runs of ``capture2face bench`` on a shared machine drift by +-20% from minute to
minute, more than the differences worth measuring. Here the commit's ``capture2face``
package is exported (``git archive``) into a temporary folder as ``capture2face_baseline``,
both packages draw their own default avatar with ``run``'s render options (wrinkles
``auto``, the influence view from the same draw, one sample + FXAA on a software GL) in
their own GL contexts, and the two alternate round by round, the first one swapping each
round. Each round renders the same head sweep (``eval.render_speed.sweep_states``).

Prints one JSON object: per version the median wall and processor milliseconds a frame,
and the medians of the per-round ratios ``rate_ratio`` (this tree's frames per second over
the commit's) and ``cpu_ratio`` (processor time a frame, this tree's over the commit's).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASELINE = "capture2face_baseline"


def export_package(commit: str, folder: Path) -> None:
    """``capture2face/`` at ``commit`` into ``folder/capture2face_baseline`` (imports renamed)."""
    data = subprocess.run(["git", "archive", commit, "capture2face"], cwd=ROOT, check=True,
                          capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(folder, filter="data")
    package = folder / BASELINE
    (folder / "capture2face").rename(package)
    word = re.compile(r"\bcapture2face\b")
    for path in package.rglob("*.py"):
        path.write_text(word.sub(BASELINE, path.read_text()))


def renderer(package: str, size: int, frames: int):
    """(renderer, states) of ``package``'s default avatar with ``run``'s render options."""
    import importlib

    render = importlib.import_module(f"{package}.render")
    try:  # the render-speed module's home since the layered package (issue 23)
        benchmark = importlib.import_module(f"{package}.eval.render_speed")
    except ModuleNotFoundError:
        benchmark = importlib.import_module(f"{package}.render.benchmark")
    pipeline = importlib.import_module(f"{package}.pipeline")
    avatar = importlib.import_module(f"{package}.rig.avatar")
    rig = avatar.default_avatar()
    options = pipeline.run_render_options(pipeline.RunOptions(size=size, wrinkles="auto"))
    r = render.Renderer.create_from_options(rig, options)
    states = benchmark.sweep_states(rig, frames, options.fov_y_degrees)
    with r.ctx:
        r.render_with_influence(states[0])  # compile and first use out of the timing
    return r, states


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("commit", help="the commit to compare with, e.g. f0965a6")
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--size", type=int, default=512)
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="render-vs-commit-") as tmp:
        export_package(args.commit, Path(tmp))
        sys.path.insert(0, tmp)
        sys.path.insert(0, str(ROOT))
        versions = {"commit": renderer(BASELINE, args.size, args.frames),
                    "tree": renderer("capture2face", args.size, args.frames)}
        wall: dict[str, list[float]] = {k: [] for k in versions}
        cpu: dict[str, list[float]] = {k: [] for k in versions}
        names = list(versions)
        for k in range(args.rounds):
            for name in names if k % 2 else names[::-1]:
                r, states = versions[name]
                with r.ctx:  # two standalone contexts: this one current
                    r.ctx.finish()
                    start, start_cpu = time.perf_counter(), time.process_time()
                    for state in states:
                        r.render_with_influence(state)
                    r.ctx.finish()
                    wall[name].append(1000.0 * (time.perf_counter() - start) / len(states))
                    cpu[name].append(1000.0 * (time.process_time() - start_cpu) / len(states))
        gl = versions["tree"][0].gl_renderer
        for r, _ in versions.values():
            with r.ctx:
                r.close()
    rate = np.array(wall["commit"]) / np.array(wall["tree"])
    cpu_ratio = np.array(cpu["tree"]) / np.array(cpu["commit"])
    print(json.dumps({
        "commit": args.commit, "size": args.size, "frames": args.frames, "rounds": args.rounds, "gl_renderer": gl,
        "wall_ms_per_frame": {k: round(float(np.median(v)), 2) for k, v in wall.items()},
        "cpu_ms_per_frame": {k: round(float(np.median(v)), 2) for k, v in cpu.items()},
        "rate_ratio": round(float(np.median(rate)), 3),
        "rate_ratio_range": [round(float(rate.min()), 3), round(float(rate.max()), 3)],
        "cpu_ratio": round(float(np.median(cpu_ratio)), 3),
        "cpu_ratio_range": [round(float(cpu_ratio.min()), 3), round(float(cpu_ratio.max()), 3)],
    }, indent=1))


if __name__ == "__main__":
    main()

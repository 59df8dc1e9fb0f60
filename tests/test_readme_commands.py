"""Every ``capture2face`` command README.md shows runs as a user types it (verbatim: no
``-q``, progress bars and summaries on), exits 0 without a traceback, and writes what it
should.

The contract with the README: each line of a fenced ``bash`` block that starts with
``capture2face `` is a command (and, in a line chaining commands with ``&&``, the part after
the last ``&& `` when it starts with ``capture2face ``). Synopses with placeholders belong
in ``text`` blocks. The commands run in README order, from a scratch folder holding a
``sample_videos`` link to the repository's, so ``out/`` is theirs alone.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SAMPLE = ROOT / "sample_videos" / "sample.mp4"


def readme_commands(text: str) -> list[str]:
    """The ``capture2face`` command lines of ``text``'s bash blocks, in order, once each."""
    commands: list[str] = []
    for block in re.findall(r"^```bash[ \t]*\n(.*?)^```", text, flags=re.M | re.S):
        for line in block.splitlines():
            line = line.strip()
            if not line.startswith("capture2face ") and "&& " in line:
                line = line.rsplit("&& ", 1)[1].strip()
            if line.startswith("capture2face ") and line not in commands:
                commands.append(line)
    return commands


def video_frames(path: Path) -> tuple[int, int, int]:
    """(decoded frames, width, height) of a video, counted by decoding it."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        n = sum(1 for _ in container.decode(stream))
        return n, stream.codec_context.width, stream.codec_context.height


SAMPLE_FRAMES = 120  # sample_videos/sample.mp4: 4 s at 30 fps, 512 x 512
RUN_OUTPUTS = {"avatar.mp4", "compare.mp4", "animation.glb", "animation.npz", "livelink.csv", "report.json",
               "report.html", "track.npz"}


def check_run_folder(folder: Path) -> None:
    """A ``run`` output folder of the sample clip: every output, each with the clip's frames."""
    assert {p.name for p in folder.iterdir()} >= RUN_OUTPUTS
    report = json.loads((folder / "report.json").read_text())
    assert report["frames"] == SAMPLE_FRAMES
    assert report["tracked_frames"] >= 0.9 * SAMPLE_FRAMES  # one face, always in view
    assert report["warnings"] == []
    assert video_frames(folder / "avatar.mp4") == (SAMPLE_FRAMES, 512, 512)  # run's default --size
    assert video_frames(folder / "compare.mp4") == (SAMPLE_FRAMES, 3 * 512, 512)
    assert len((folder / "livelink.csv").read_text().splitlines()) == 1 + SAMPLE_FRAMES


def check_run(out: Path, stdout: str, stderr: str) -> None:
    check_run_folder(out / "sample")
    assert "wrote out/sample (120 frames" in stdout


def check_track(out: Path, stdout: str, stderr: str) -> None:
    from capture2face.tracking import Track

    track = Track.load(out / "track.npz")
    assert track.n_frames == SAMPLE_FRAMES and (track.width, track.height) == (512, 512)
    assert track.tracked_frames >= 0.9 * SAMPLE_FRAMES
    assert video_frames(out / "overlay.mp4") == (SAMPLE_FRAMES, 512, 512)
    assert stdout.startswith(f"out/track.npz: {SAMPLE_FRAMES} frames")


def check_eval_fidelity(out: Path, stdout: str, stderr: str) -> None:
    result = json.loads((out / "fidelity.json").read_text())
    (clip,) = result["clips"]
    assert clip["clip"] == "sample" and clip["frames"] == SAMPLE_FRAMES
    assert "| sample |" in stdout and result["summary"] in stdout


def check_batch(out: Path, stdout: str, stderr: str) -> None:
    report = json.loads((out / "batch" / "batch_report.json").read_text())
    assert report["summary"] == {"ok": 1, "failed": 0, "skipped": 0, "pending": 0}
    assert [c["frames"] for c in report["clips"]] == [SAMPLE_FRAMES]
    check_run_folder(out / "batch" / "sample")
    assert "1 clips, 0 failed" in stdout


def check_synth(out: Path, stdout: str, stderr: str) -> None:
    from capture2face.synth import SyntheticTruth

    assert video_frames(out / "synthetic.mp4") == (30, 256, 256)
    truth = SyntheticTruth.load(out / "synthetic.truth.npz")
    assert len(truth.bone_positions) == 30


def check_eval_synthetic(out: Path, stdout: str, stderr: str) -> None:
    result = json.loads((out / "synthetic.json").read_text())
    assert result == json.loads(stdout)  # stdout stays plain JSON; the summary goes to stderr
    assert (result["frames"], result["size"]) == (60, 256)
    assert result["frames_scored"] >= 50
    assert "truth's neutral:" in stderr and "goals met" in stderr


def check_avatar(out: Path, stdout: str, stderr: str) -> None:
    from capture2face import default_avatar, import_glb

    rig, default = import_glb(out / "avatar.glb"), default_avatar()
    assert (rig.n_vertices, rig.n_bones, rig.n_morphs) == (default.n_vertices, default.n_bones, default.n_morphs)
    assert stdout.strip() == "wrote out/avatar.glb"


def check_bench(out: Path, stdout: str, stderr: str) -> None:
    figures = json.loads((out / "bench.json").read_text())
    assert figures == json.loads(stdout)  # stdout stays plain JSON; the summary goes to stderr
    assert (figures["size"], figures["frames"]) == (128, 60)
    goals = figures["goals"]
    met = sum(bool(v) for v in goals.values())
    assert f"goals met {met}/{len(goals)}" in stderr


# Each README command -> what checks its outputs (paths relative to the scratch folder).
EXPECTED = {
    "capture2face run sample_videos/sample.mp4 -o out": check_run,
    "capture2face track sample_videos/sample.mp4 -o out/track.npz --overlay out/overlay.mp4": check_track,
    "capture2face eval fidelity out/sample --json out/fidelity.json": check_eval_fidelity,
    "capture2face batch sample_videos/sample.mp4 -o out/batch --jobs 1": check_batch,
    "capture2face synth -o out/synthetic.mp4 --frames 30 --size 256": check_synth,
    "capture2face eval synthetic --frames 60 --size 256 --json out/synthetic.json": check_eval_synthetic,
    "capture2face avatar --export out/avatar.glb": check_avatar,
    "capture2face bench --frames 60 --size 128 --json out/bench.json": check_bench,
}


def test_readme_shows_exactly_the_tested_commands():
    """A command added to or removed from the README fails here until this file knows
    what it writes."""
    commands = readme_commands(README.read_text(encoding="utf-8"))
    assert set(commands) == set(EXPECTED), (
        f"in README, not tested: {sorted(set(commands) - set(EXPECTED))}; "
        f"tested, not in README: {sorted(set(EXPECTED) - set(commands))}")


def test_readme_command_extraction():
    text = ("```bash\npip install -e . && capture2face run a.mp4 -o out\ncapture2face avatar\n"
            "echo capture2face no\n```\n```text\ncapture2face run CLIP -o OUT\n```\n"
            "```bash\ncapture2face avatar\n```\n")
    assert readme_commands(text) == ["capture2face run a.mp4 -o out", "capture2face avatar"]


def _console_command(line: str) -> list[str]:
    """``line`` as argv: the ``capture2face`` console script beside this Python when it is
    installed, else ``python -m capture2face`` with the same arguments."""
    argv = shlex.split(line)
    script = Path(sys.executable).with_name("capture2face")
    return [str(script) if script.is_file() else sys.executable, *([] if script.is_file() else ["-m", "capture2face"]),
            *argv[1:]]


@pytest.fixture(scope="module")
def ran(tmp_path_factory) -> dict:
    """Every README command run in README order in one scratch folder:
    command -> (returncode, stdout, stderr), and the folder under ``"cwd"``."""
    cwd = tmp_path_factory.mktemp("readme")
    (cwd / "sample_videos").symlink_to(ROOT / "sample_videos", target_is_directory=True)
    # The package under test, whichever capture2face the environment has installed.
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    results: dict = {"cwd": cwd}
    for line in readme_commands(README.read_text(encoding="utf-8")):
        proc = subprocess.run(_console_command(line), cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=600)
        results[line] = (proc.returncode, proc.stdout, proc.stderr)
    return results


@pytest.mark.slow
@pytest.mark.parametrize("line", list(EXPECTED))
def test_readme_command_runs_verbatim(ran, line):
    if line not in ran:
        pytest.fail(f"not in README.md: {line}")
    code, stdout, stderr = ran[line]
    assert code == 0, f"{line}: exit {code}\n{stderr[-3000:]}"
    assert "Traceback" not in stderr, f"{line}:\n{stderr[-3000:]}"
    EXPECTED[line](ran["cwd"] / "out", stdout, stderr)


def test_sample_clip_frames():
    assert video_frames(SAMPLE) == (SAMPLE_FRAMES, 512, 512)

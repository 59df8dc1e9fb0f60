"""The measurement scripts in tools/ run from the repository, their figures are the CLI's,
and the docs cite only commands anyone with the repository can run."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import REPO

TOOLS = sorted((REPO / "tools").glob("*.py"))
SAMPLE = REPO / "sample_videos" / "sample.mp4"
ENV = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
# A script run from a machine path (`python /work/ref/x.py`, `bash /tmp/y.sh`) or named there.
MACHINE_SCRIPT = re.compile(r"(?:python[\d.]*|bash|sh)\s+/(?:work|tmp)/\S+|/(?:work|tmp)/\S+\.(?:py|sh)\b")


def _tool(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout,
                          env=ENV, check=False)


@pytest.mark.parametrize("script", TOOLS, ids=[t.stem for t in TOOLS])
def test_every_tool_prints_its_help(script):
    done = _tool(os.fspath(script.relative_to(REPO)), "--help", timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "usage:" in done.stdout


def test_the_measurement_tools_are_there():
    assert {"track_clips", "fidelity_on_tracks", "wrinkle_goals"} <= {t.stem for t in TOOLS}


def _doc_files() -> list[Path]:
    docs = [p for p in (REPO / "docs").rglob("*.md") if "history" not in p.relative_to(REPO / "docs").parts]
    return [REPO / "README.md", *sorted(docs)]


def test_machine_script_pattern_finds_what_it_should():
    assert MACHINE_SCRIPT.search("tracks (`python /work/ref/fid.py [CHARACTER]`)")
    assert MACHINE_SCRIPT.search("see /tmp/x/goals21.py")
    assert not MACHINE_SCRIPT.search("`python tools/fidelity_on_tracks.py --character ict-a.glb`")


def test_docs_run_no_script_from_a_machine_path():
    """Figures come from the CLI or tools/: no doc (docs/history aside) runs a script at a
    machine path (/work/..., /tmp/...)."""
    found = [f"{doc.relative_to(REPO)}:{n}: {m.group(0)}"
             for doc in _doc_files() for n, line in enumerate(doc.read_text(encoding="utf-8").splitlines(), 1)
             for m in MACHINE_SCRIPT.finditer(line)]
    assert found == []


@pytest.mark.slow
def test_fidelity_on_tracks_gives_eval_fidelitys_figures(tmp_path):
    """tools/fidelity_on_tracks.py's JSON (a cached track, then the retarget and the
    measures) equals ``capture2face eval fidelity``'s on the same clip, to the last digit."""
    cli = _tool("-m", "capture2face", "eval", "fidelity", os.fspath(SAMPLE), "--json", os.fspath(tmp_path / "cli.json"),
                "--quiet")
    assert cli.returncode == 0, cli.stderr[-2000:]
    args = ["tools/fidelity_on_tracks.py", os.fspath(SAMPLE), "--cache", os.fspath(tmp_path / "tracks")]
    first = _tool(*args, "--json", os.fspath(tmp_path / "tool.json"))
    assert first.returncode == 0, first.stderr[-2000:]
    assert (tmp_path / "tracks" / "sample" / "track.npz").is_file()
    again = _tool(*args, "--json", os.fspath(tmp_path / "again.json"))  # from the cache this time
    assert again.returncode == 0, again.stderr[-2000:]
    expected = json.loads((tmp_path / "cli.json").read_text())
    assert json.loads((tmp_path / "tool.json").read_text()) == expected
    assert json.loads((tmp_path / "again.json").read_text()) == expected
    assert first.stdout.splitlines()[-1] == cli.stdout.splitlines()[-1]  # the summary line


def test_protocol_sheet_shows_every_step(tmp_path):
    """tools/protocol_sheet.py: the neutral and every step in rows of 7 cells, each step's
    face unlike the neutral's."""
    import cv2
    import numpy as np

    from capture2face.calibration.protocol import PROTOCOL
    from tests.helpers import shared_character

    rows = -(-(len(PROTOCOL) + 1) // 7)
    out = tmp_path / "sheet.png"
    done = _tool("tools/protocol_sheet.py", os.fspath(out), "--cell", "64",
                 "--character", os.fspath(shared_character("ict-a.glb")), timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    sheet = cv2.imread(os.fspath(out)).astype(np.float64)
    assert sheet.shape[1] == 7 * 64 and sheet.shape[0] % rows == 0 and sheet.shape[0] > rows * 64
    row = sheet.shape[0] // rows
    cells = [sheet[r * row:r * row + 64, k * 64:(k + 1) * 64] for r in range(rows) for k in range(7)]
    differences = [np.abs(c - cells[0]).mean() for c in cells[1:len(PROTOCOL) + 1]]
    assert min(differences) > 0.3, differences


def test_calibration_doc_lists_the_protocol_in_order():
    from capture2face.calibration.protocol import STEP_NAMES

    text = (REPO / "docs" / "calibration.md").read_text(encoding="utf-8")
    found = re.findall(r"^\d+\. \*\*(\w+)\*\*", text, re.M)
    assert found == list(STEP_NAMES)
    assert (REPO / "docs" / "calibration_protocol.jpg").stat().st_size < 400_000


def test_calibration_across_takes_counts_goals_over_every_take():
    """The spread table: mean r [lowest, highest] / mean MAE over a performance's takes, a
    goal met only where r >= 0.9 and the MAE is below MediaPipe's."""
    sys.path.insert(0, os.fspath(REPO / "tools"))
    try:
        import calibration_across_takes as tool
    finally:
        sys.path.remove(os.fspath(REPO / "tools"))
    good, bad = [0.95, 0.02, 0.05], [0.95, 0.06, 0.05]  # r met; the MAE below / above the raw score's
    rows = {"perf|t1": dict.fromkeys(tool.GOALS, good), "perf|t2": dict.fromkeys(tool.GOALS, bad)}
    rows["perf|t2"]["browDownLeft"] = [0.35, 0.04, 0.05]  # MAE below, r not: not met
    rows["perf|t2"]["jawOpen"] = [0.92, 0.01, 0.05]
    assert tool.met(rows["perf|t1"]) == 8 and tool.met(rows["perf|t2"]) == 1
    line = tool.table(rows).splitlines()[2]
    assert line.startswith("| perf (t1, t2) |") and line.endswith("| 9 of 16 |")
    assert "0.65 [0.35, 0.95] / 0.030" in line  # browDownLeft over the two takes
    rows["perf|together"] = dict(rows["perf|t2"])  # the takes together: a row of its own
    lines = tool.table(rows).splitlines()
    assert lines[2] == line and lines[3].startswith("| perf (all 2 together) |")
    assert "| 0.35 / 0.040 |" in lines[3] and lines[3].endswith("| 1 of 8 |")


def test_calibration_diagnose_finds_the_lag_and_what_the_error_follows():
    """A curve two frames late, raised by another truth curve: the tool's figures say so."""
    sys.path.insert(0, os.fspath(REPO / "tools"))
    try:
        import calibration_diagnose as tool
    finally:
        sys.path.remove(os.fspath(REPO / "tools"))
    rng = np.random.default_rng(0)
    truth = np.clip(np.convolve(rng.normal(size=400), np.ones(15) / 15, "same") + 0.3, 0, 1)
    funnel, noise = rng.uniform(0, 1, 400), rng.uniform(0, 1, 400)
    curve = np.r_[truth[:2], truth[:-2]] + 0.3 * funnel
    fig = tool.curve_figures(curve, truth, {"mouthFunnel": funnel, "noise": noise, "still": np.zeros(400)}, top=2)
    assert fig["lag"] == 2 and fig["lag_r"] > fig["r"]
    assert list(fig["error_r"]) == ["mouthFunnel", "noise"] and fig["error_r"]["mouthFunnel"] > 0.5
    worst = tool.worst_frames(curve, truth, curve, {"mouthFunnel": funnel}, fps=30, count=3)
    frames = [w["frame"] for w in worst]
    assert len(frames) == 3 and min(np.diff(frames)) >= 30
    pose = np.c_[rng.normal(size=(400, 2)), np.ones(400)]
    fits = tool.pose_fits({"p": (truth + pose[:, 0], truth, pose)})
    assert fits["p"]["p"] > 0.99  # the pose's part taken off in-sample


def test_calibration_bound_fits_what_the_reading_holds_and_nothing_else():
    """The ceiling's fits: a curve that is a line of the reading is recovered on new frames
    by the ridge, a curve that is a bump of it by the radial basis better than by the ridge,
    and a curve the reading does not hold by neither."""
    sys.path.insert(0, os.fspath(REPO / "tools"))
    try:
        import calibration_bound as tool
    finally:
        sys.path.remove(os.fspath(REPO / "tools"))
    rng = np.random.default_rng(1)
    x_fit, x_new = rng.normal(size=(600, 6)), rng.normal(size=(300, 6))
    line = lambda x: x @ np.array([0.08, -0.05, 0.03, 0, 0, 0]) + 0.5  # noqa: E731
    bump = lambda x: np.exp(-(x[:, 0] ** 2 + x[:, 1] ** 2))  # noqa: E731
    r, mae, ridge = tool.best_fit(x_fit, line(x_fit) + 0.01 * rng.normal(size=600), x_new, line(x_new))
    assert r > 0.99 and mae < 0.02 and ridge in tool.RIDGES
    r_line = tool.best_fit(x_fit, bump(x_fit), x_new, bump(x_new))[0]
    r_rbf, _, setting = tool.best_fit(x_fit, bump(x_fit), x_new, bump(x_new), "rbf")
    assert r_line < 0.3 and r_rbf > 0.9 and setting[0] in tool.RBF_WIDTHS
    unrelated = rng.uniform(0, 1, 300)
    assert max(tool.best_fit(x_fit, rng.uniform(0, 1, 600), x_new, unrelated, kind)[0]
               for kind in ("ridge", "rbf")) < 0.3


def test_morph_ranges_gives_p99_or_the_mean_over_frames():
    """Each ARKit-named morph's solved weight beside its curve: p99 over the clip, or the
    mean over ``--frames`` (one expression, as d18's grimace in docs/characters.md)."""
    from types import SimpleNamespace

    import numpy as np

    sys.path.insert(0, os.fspath(REPO / "tools"))
    try:
        import morph_ranges as tool
    finally:
        sys.path.remove(os.fspath(REPO / "tools"))
    curve = np.linspace(0.0, 1.0, 101)
    animation = SimpleNamespace(arkit_names=["jawOpen", "mouthShrugUpper"],
                                arkit_weights=np.stack([curve, np.zeros(101)], 1),
                                blend_names=["jawOpen", "mouthShrugUpper", "viseme_aa"],
                                blend_weights=np.stack([curve / 2, np.ones(101), curve], 1))
    rows = {n: (c, w) for n, c, w in tool.morph_ranges(None, animation)}
    assert set(rows) == {"jawOpen", "mouthShrugUpper"}
    assert rows["jawOpen"] == pytest.approx((0.99, 0.495)) and rows["mouthShrugUpper"] == (0.0, 1.0)
    rows = {n: (c, w) for n, c, w in tool.morph_ranges(None, animation, ["jawOpen"], slice(10, 21))}
    assert rows == {"jawOpen": pytest.approx((0.15, 0.075))}


def test_disc_light_reads_the_render_s_normals_against_the_shape_s(avatar):
    """Each shading disc's n·l by the renderer's normals, the shape's smooth normals and its
    facets: unchanged at rest, and on a smile the built-in avatar's exact morph normals lose
    the light its facets lose (the check that put the RPM female's dark cheek on her shape)."""
    import numpy as np

    sys.path.insert(0, os.fspath(REPO / "tools"))
    try:
        import disc_light as tool
    finally:
        sys.path.remove(os.fspath(REPO / "tools"))
    rest = tool.disc_light(avatar, avatar.bone_rest, np.zeros(avatar.n_morphs, np.float32))
    assert set(rest) == {"cheek_right", "cheek_left", "chin"}
    for row in rest.values():
        assert row["vertices"][0] > 0
        for how in ("renderer", "smooth", "facets"):
            assert row[how][0] == pytest.approx(row[how][1], abs=1e-6)
    weights = np.zeros(avatar.n_morphs, np.float32)
    weights[[m for m, n in enumerate(avatar.morph_names) if n.startswith("mouthSmile")]] = 1.0
    smile = tool.disc_light(avatar, avatar.bone_rest, weights)
    for row in smile.values():
        change = {how: row[how][1] - row[how][0] for how in ("renderer", "facets")}
        assert change["renderer"] == pytest.approx(change["facets"], abs=0.03)

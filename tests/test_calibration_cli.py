"""The calibration's plumbing: ``capture2face calibrate``, ``--calibration`` on run, track
and batch, report.json's and report.html's calibration section (the calibration itself:
tests/test_calibration.py)."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from capture2face import batch
from capture2face.batch import clip_options, expand_inputs
from capture2face.calibration import ActorCalibration
from capture2face.cli import main
from capture2face.pipeline import RunOptions, options_json
from capture2face.pipeline.options import input_files
from capture2face.pipeline.report.tables import calibration_table
from capture2face.tracking import TrackOptions
from capture2face.tracking.track import Track

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_videos" / "sample.mp4"



def _one_line_error(capsys, code: int, argv: list[str], *words: str) -> None:
    assert main(argv) == code
    err = capsys.readouterr().err.strip()
    assert err.startswith("capture2face: error: ") and "\n" not in err, err
    for word in words:
        assert word in err, err


# ---- fast: the flags' checks, the options, batch's sidecars ------------------------------
@pytest.mark.parametrize("content", [None, "garbage", '{"format": "something else"}', "folder"])
def test_a_missing_or_bad_calibration_file_is_one_line_error(tmp_path, capsys, no_tracking, content):
    path = tmp_path / ("cal" if content == "folder" else "actor.json")
    if content == "folder":
        path.mkdir()
    elif content is not None:
        path.write_text(content)
    for argv in (["run", str(SAMPLE), "-o", str(tmp_path / "out")],
                 ["track", str(SAMPLE), "-o", str(tmp_path / "t.npz")],
                 ["batch", str(SAMPLE), "-o", str(tmp_path / "out"), "--jobs", "1"]):
        _one_line_error(capsys, 2, argv + ["--calibration", str(path)], "--calibration", str(path))
    assert not (tmp_path / "out" / "sample").exists() and not (tmp_path / "t.npz").exists()


def test_calibrate_refuses_what_is_not_a_take(tmp_path, capsys):
    _one_line_error(capsys, 2, ["calibrate", str(tmp_path / "none.mp4"), "-o", str(tmp_path / "a.json")],
                    "no such file")
    # one bad take among several: refused before any take is tracked
    _one_line_error(capsys, 2, ["calibrate", str(SAMPLE), str(tmp_path / "none.mp4"), "-o", str(tmp_path / "a.json")],
                    "none.mp4")
    (tmp_path / "notes.mp4").write_text("not a video")
    _one_line_error(capsys, 2, ["calibrate", str(tmp_path / "notes.mp4"), "-o", str(tmp_path / "a.json")])
    assert not (tmp_path / "a.json").exists()


def test_without_calibration_the_options_and_inputs_are_as_before():
    options = RunOptions()
    assert "calibration" not in options_json(options)
    assert set(input_files(SAMPLE, options)) == {"clip"}


def test_the_calibration_is_stored_by_absolute_path_and_fingerprinted(tmp_path, monkeypatch):
    (tmp_path / "actor.json").write_text("{}")
    monkeypatch.chdir(tmp_path)
    options = RunOptions(track=TrackOptions(calibration="actor.json"))
    assert options_json(options)["calibration"] == str(tmp_path / "actor.json")
    assert input_files(SAMPLE, options)["calibration"] == "actor.json"
    assert "track" not in options_json(options)  # stored once, flat, as the other file options


def test_batch_finds_rom_sidecars_and_never_runs_them(tmp_path):
    for name in ("a.mp4", "a.rom.mp4", "b.mp4", "b.rom.json", "c.mp4", "c.neutral.mp4"):
        shutil.copy(SAMPLE, tmp_path / name) if name.endswith(".mp4") else (tmp_path / name).write_text("{}")
    clips = {c.name: c for c in expand_inputs([tmp_path])}
    assert sorted(clips) == ["a", "b", "c"]
    assert clips["a"].rom == str(tmp_path / "a.rom.mp4") and clips["b"].rom == str(tmp_path / "b.rom.json")
    assert clips["c"].rom is None and clips["c"].neutral == str(tmp_path / "c.neutral.mp4")
    assert clip_options(clips["b"], RunOptions()).track.calibration == str(tmp_path / "b.rom.json")
    # The batch's own --calibration wins over a clip's sidecar, as a batch's rest does.
    shared = RunOptions(track=TrackOptions(calibration="all.json"))
    assert clip_options(clips["b"], shared).track.calibration == "all.json"


def test_batch_learns_a_take_once_in_the_parent(tmp_path, monkeypatch):
    """One take for the whole batch, and one sidecar take shared by name: each learned once,
    before any clip runs; the clips get what was learned, report.json the take's path."""
    for name in ("a.mp4", "b.mp4", "rom.mp4"):
        shutil.copy(SAMPLE, tmp_path / name)
    learned, ran = [], []
    fake = ActorCalibration.__new__(ActorCalibration)
    fake.source = str(tmp_path / "rom.mp4")

    def learn(take, options, progress):
        learned.append(Path(take).name)
        return fake

    def run_clip(path, out, name, options):
        ran.append((name, options.track.calibration))
        return {"status": "ok", "seconds": 0.0, "error": None, "frames": 1, "output_dir": str(Path(out) / name)}

    monkeypatch.setattr(batch, "learn_calibration", learn)
    monkeypatch.setattr(batch, "_run_clip", run_clip)
    out = tmp_path / "out"
    report = batch.run_batch([tmp_path / "a.mp4", tmp_path / "b.mp4"], out,
                             RunOptions(track=TrackOptions(calibration=str(tmp_path / "rom.mp4"))), jobs=1,
                             progress=False)
    assert learned == ["rom.mp4"] and [c for _, c in ran] == [fake, fake]
    assert report["options"]["calibration"] == str(tmp_path / "rom.mp4")
    # A sidecar take: learned for its clip (a broken one fails only its clip).
    shutil.copy(SAMPLE, tmp_path / "a.rom.mp4")
    learned.clear(), ran.clear()
    report = batch.run_batch([tmp_path / "a.mp4", tmp_path / "b.mp4"], out, RunOptions(), jobs=1, progress=False)
    assert learned == ["a.rom.mp4"] and ran == [("a", fake), ("b", None)]
    assert report["clips"][0]["rom"] == str(tmp_path / "a.rom.mp4")


def test_report_html_calibration_table():
    section = {"source": "rom.mp4", "curves": {"jawOpen": {"gain": 1.1, "offset": 0.0, "steps": ["jaw_open"]}},
               "steps": [{"name": "jaw_open", "found": True, "frames": [10, 40], "hold": [20, 30], "match": 0.91,
                          "before": {"jawOpen": 0.41}, "after": {"jawOpen": 0.93}},
                         {"name": "frown", "found": False, "frames": None, "hold": None, "match": None,
                          "before": {}, "after": {}}], "warnings": []}
    html = calibration_table(section)
    assert "1 of 2 steps found" in html and "10–40" in html and "jawOpen 0.41" in html and "jawOpen 0.93" in html
    assert "not found" in html and calibration_table(None) == ""


# ---- slow: a ROM take of ict-a, calibrated and used ---------------------------------------
@pytest.mark.slow
def test_calibrate_writes_an_actor_json_that_round_trips(actor_json, tmp_path):
    calibration = ActorCalibration.load(actor_json)
    assert sum(s.found for s in calibration.steps) >= 15
    assert calibration.curves
    calibration.save(tmp_path / "again.json")
    assert ActorCalibration.load(tmp_path / "again.json").to_json() == calibration.to_json()
    assert json.loads((tmp_path / "again.json").read_text()) == json.loads(actor_json.read_text())


@pytest.mark.slow
def test_calibrate_takes_several_takes_into_one_actor_json(rom_take, tmp_path, capsys):
    """Two takes: one actor.json holding both, the summary naming them, each take's warnings
    named after it; report.html shows a table a take."""
    second = tmp_path / "second.mp4"
    shutil.copy(rom_take, second)
    out = tmp_path / "actor.json"
    assert main(["calibrate", str(rom_take), str(second), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "2 takes, steps found " in captured.out
    calibration = ActorCalibration.load(out)
    assert [Path(t.source).name for t in calibration.takes] == [rom_take.name, "second.mp4"]
    assert calibration.more_takes[0].curves == calibration.curves  # the same take, learned alike
    warned = [line for line in captured.err.splitlines() if line.startswith("capture2face: warning: ")]
    assert all(str(rom_take) in line or str(second) in line for line in warned)
    from capture2face.pipeline.calibration import calibration_report

    html = calibration_table(calibration_report(calibration))
    assert html.count('<table class="calibration">') == 2 and "mean of 2 takes" in html


def _livelink(folder: Path) -> dict[str, np.ndarray]:
    with open(folder / "livelink.csv", newline="") as f:
        rows = list(csv.reader(f))
    return {name: np.array([float(r[k]) for r in rows[1:]]) for k, name in enumerate(rows[0]) if k >= 2}


@pytest.mark.slow
def test_run_with_a_calibration_writes_it_and_an_edited_gain_changes_livelink(actor_json, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["-q", "run", str(SAMPLE), "-o", str(out), "--size", "64", "--calibration", str(actor_json)]) == 0
    report = json.loads((out / "sample" / "report.json").read_text())
    assert "calibration.json" in report["outputs"] and (out / "sample" / "calibration.json").is_file()
    assert ActorCalibration.load(out / "sample" / "calibration.json").to_json() == \
        ActorCalibration.load(actor_json).to_json()
    section = report["calibration"]
    assert set(section) == {"source", "steps", "curves", "warnings"}
    assert {"name", "found", "frames", "hold", "match", "before", "after"} <= set(section["steps"][0])
    assert all(w in report["warnings"] for w in section["warnings"])
    assert report["options"]["calibration"] == str(actor_json) and "calibration" in report["inputs"]
    assert "<h2>Calibration</h2>" in (out / "sample" / "report.html").read_text()
    before = _livelink(out / "sample")
    # The curve the calibration moves most in this clip, switched off in actor.json.
    data = json.loads(actor_json.read_text())
    name = max(data["curves"], key=lambda n: before[n[0].upper() + n[1:]].sum())
    column = name[0].upper() + name[1:]
    assert before[column].max() > 0.05
    data["curves"][name].update(gain=0.0, offset=0.0)
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    assert main(["-q", "run", str(SAMPLE), "-o", str(tmp_path / "out2"), "--size", "64", "--calibration",
                 str(edited)]) == 0
    after = _livelink(tmp_path / "out2" / "sample")
    assert np.allclose(after[column], 0.0)
    assert all(np.allclose(after[c], before[c], atol=1e-6) for c in before if c != column
               and c[0].lower() + c[1:] not in data["curves"])  # the uncalibrated columns stay


@pytest.mark.slow
def test_track_and_batch_carry_the_calibration(actor_json, tmp_path):
    assert main(["-q", "track", str(SAMPLE), "-o", str(tmp_path / "t.npz"), "--calibration", str(actor_json)]) == 0
    track = Track.load(tmp_path / "t.npz")
    assert json.loads(track.calibration)["source"] == ActorCalibration.load(actor_json).source
    assert track.rest_source == "clip"  # the clip keeps its own rest
    # A batch: the clip's CLIP.rom.json; --resume runs it again once the calibration changed.
    shutil.copy(SAMPLE, tmp_path / "clip.mp4")
    shutil.copy(actor_json, tmp_path / "clip.rom.json")
    out = tmp_path / "out"
    argv = ["-q", "batch", str(tmp_path / "clip.mp4"), "-o", str(out), "--size", "64", "--jobs", "1"]
    assert main(argv) == 0
    report = json.loads((out / "clip" / "report.json").read_text())
    assert report["options"]["calibration"] == str(tmp_path / "clip.rom.json")
    assert (out / "clip" / "calibration.json").is_file()
    assert main(argv + ["--resume"]) == 0
    assert json.loads((out / "batch_report.json").read_text())["clips"][0]["status"] == "skipped"
    data = json.loads((tmp_path / "clip.rom.json").read_text())
    next(iter(data["curves"].values()))["gain"] = 1.5
    (tmp_path / "clip.rom.json").write_text(json.dumps(data))
    assert main(argv + ["--resume"]) == 0
    entry = json.loads((out / "batch_report.json").read_text())["clips"][0]
    assert entry["status"] == "ok" and "calibration" in entry["rerun"]
    # One --calibration for the whole batch: it wins over the clip's own.
    assert main(argv[:4] + [str(tmp_path / "all"), *argv[5:], "--calibration", str(actor_json)]) == 0
    report = json.loads((tmp_path / "all" / "clip" / "report.json").read_text())
    assert report["options"]["calibration"] == str(actor_json) and report["calibration"]["steps"]

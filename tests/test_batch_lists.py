"""``capture2face batch``: list files as users write them, resume across folders and
character files, Ctrl-C with clips queued (issue 33, items 5, 8-12)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from capture2face import cli
from capture2face.batch import expand_inputs
from capture2face.pipeline import RunOptions


def _entries(out: Path) -> dict[str, dict]:
    return {Path(c["path"]).name: c for c in json.loads((out / "batch_report.json").read_text())["clips"]}


# ---- lists (items 9, 10, 11) ----------------------------------------------------------------
def test_a_list_keeps_hashes_in_names_quotes_and_a_bom(tmp_path, capsys):
    for name in ["take#2.mp4", "d3s.mp4", "my take.mp4", "rest #1.jpg"]:
        (tmp_path / name).write_bytes(b"not a video")  # each clip fails on its content, found by its name
    (tmp_path / "list.txt").write_bytes(
        "\ufefftake#2.mp4   # the good one\n"  # a BOM, then a '#' inside a name
        '"d3s.mp4"\n'
        "\"my take.mp4\" | 'rest #1.jpg'\n".encode())
    code = cli.main(["-q", "batch", str(tmp_path / "list.txt"), "-o", str(tmp_path / "out"), "--jobs", "1"])
    err = capsys.readouterr().err
    assert code == 1, err  # the clips are not videos: each names its own file
    entries = _entries(tmp_path / "out")
    assert set(entries) == {"take#2.mp4", "d3s.mp4", "my take.mp4"}, entries
    assert all(Path(e["path"]).is_file() and "no such file" not in e["error"] for e in entries.values()), entries
    assert Path(entries["my take.mp4"]["neutral"]) == tmp_path / "rest #1.jpg"
    assert "\ufeff" not in err and '"' not in err


@pytest.mark.parametrize("text, clip, neutral", [
    ("take#2.mp4\n", "take#2.mp4", None),
    ("take#2.mp4\t# tab, then a comment\n", "take#2.mp4", None),
    ("#take.mp4\n  # indented comment\nx.mp4#y\n", "x.mp4#y", None),
    ("\ufeff'd3s.mp4'\r\n", "d3s.mp4", None),  # a BOM and Windows line ends
    ('"a | b #1.mp4"\t"rest.jpg"\n', "a | b #1.mp4", "rest.jpg"),
    ("it's.mp4  # an apostrophe opens no quote\n", "it's.mp4", None),
    ('"unclosed.mp4\n', '"unclosed.mp4', None),
])
def test_list_line_spellings(tmp_path, text, clip, neutral):
    (tmp_path / "l.txt").write_text(text, encoding="utf-8", newline="")
    (got,) = expand_inputs([tmp_path / "l.txt"])
    assert got.path == str(tmp_path / clip)
    assert got.neutral == (None if neutral is None else str(tmp_path / neutral))


def test_a_utf16_list_with_its_bom(tmp_path):
    (tmp_path / "l.txt").write_text("take#2.mp4\n", encoding="utf-16")  # Notepad's "Unicode"
    (got,) = expand_inputs([tmp_path / "l.txt"])
    assert got.path == str(tmp_path / "take#2.mp4")



@pytest.mark.parametrize("command", [["batch", "--jobs", "2"], ["run"]])
def test_ctrl_c_while_the_libraries_load_exits_130_in_one_line(sample_clip, tmp_path, command):
    """Ctrl-C half a second after Enter, while OpenCV, SciPy and MediaPipe import (before
    the command's own handler exists): exit 130, no KeyboardInterrupt traceback, nothing
    written. (On a machine that imports faster the signal lands in the command: the same.)"""
    import os
    import signal
    import subprocess
    import sys
    import time

    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    proc = subprocess.Popen([sys.executable, "-m", "capture2face", "-q", command[0], str(sample_clip), "-o",
                             str(tmp_path / "out"), *command[1:]], stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    try:
        time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGINT)
        err = proc.communicate(timeout=60)[1]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and "Traceback" not in err, err[-2000:]
    assert err.strip().splitlines() == ["capture2face: interrupted"], err[-2000:]
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# ---- Ctrl-C with clips queued (item 12) -----------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("to", ["group", "batch"])  # a terminal's Ctrl-C (every process), kill -INT PID
def test_ctrl_c_starts_no_queued_clip_and_exits_130_promptly(sample_clip, tmp_path, to):
    import os
    import shutil
    import signal
    import subprocess
    import sys
    import time

    clips, out = tmp_path / "clips", tmp_path / "out"
    clips.mkdir()
    for name in "abcd":
        shutil.copy(sample_clip, clips / f"{name}.mp4")
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    proc = subprocess.Popen([sys.executable, "-m", "capture2face", "-q", "batch", str(clips), "-o", str(out),
                             "--size", "64", "--jobs", "2"], stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (out.is_dir() and any(p.name.startswith(".tmp-") for p in out.iterdir())):  # a clip started
            assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
            time.sleep(0.05)
        time.sleep(1.0)
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT) if to == "group" else proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=60)[1]
        seconds = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "capture2face: interrupted", err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    assert seconds < 10, seconds  # the running clips unwind; none waits its turn
    time.sleep(3)  # a clip started after the interrupt would show now
    assert sorted(p.name for p in out.iterdir()) == ["batch_report.json"]  # no clip, nothing staged, no lock
    report = json.loads((out / "batch_report.json").read_text())
    assert report["summary"]["pending"] == 4 and report["summary"]["ok"] == 0, report


# ---- a character given relative to the working folder (item 8) ------------------------------
@pytest.mark.slow
def test_a_relative_character_is_found_again_from_another_folder(sample_clip, tmp_path):
    import os
    import shutil
    import subprocess
    import sys

    from capture2face.rig.avatar import default_avatar

    here, elsewhere = tmp_path / "here", tmp_path / "elsewhere"
    here.mkdir()
    elsewhere.mkdir()
    shutil.copy(sample_clip, here / "take.mp4")
    default_avatar().save(here / "hero.npz")
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")

    def c2f(cwd: Path, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "capture2face", "-q", *args], cwd=cwd, env=env,
                              capture_output=True, text=True, timeout=600)

    made = c2f(here, "batch", "take.mp4", "-o", "out", "--character", "hero.npz", "--size", "64", "--jobs", "1")
    assert made.returncode == 0, made.stderr[-2000:]
    stored = json.loads((here / "out" / "take" / "report.json").read_text())["options"]["character"]
    assert stored == str(here / "hero.npz")
    fidelity = c2f(elsewhere, "eval", "fidelity", "../here/out/take")
    assert fidelity.returncode == 0, fidelity.stderr[-2000:]
    again = c2f(elsewhere, "batch", "../here/take.mp4", "-o", "../here/out", "--character", "../here/hero.npz",
                "--size", "64", "--jobs", "1", "--resume")
    assert again.returncode == 0, again.stderr[-2000:]
    (entry,) = json.loads((here / "out" / "batch_report.json").read_text())["clips"]
    assert entry["status"] == "skipped", entry


# ---- --resume and the files a .gltf references (item 5) -------------------------------------
@pytest.mark.slow
def test_resume_reruns_a_gltf_whose_bin_or_texture_changed(sample_clip, tmp_path, capsys):
    import shutil

    folder = tmp_path / "hero"
    shutil.copytree(Path(__file__).parent / "data" / "real_files" / "folder", folder)
    out = tmp_path / "out"
    args = ["-q", "batch", str(sample_clip), "-o", str(out), "--character", str(folder / "character.gltf"),
            "--size", "64", "--no-audio", "--jobs", "1"]

    def resume() -> dict:
        code = cli.main([*args, "--resume"])
        assert code == 0, capsys.readouterr().err
        (entry,) = json.loads((out / "batch_report.json").read_text())["clips"]
        return entry

    assert cli.main(args) == 0, capsys.readouterr().err
    assert resume()["status"] == "skipped"
    shutil.copy(folder / "baseColor_2.png", folder / "baseColor_1.png")  # a texture edited
    entry = resume()
    assert entry["status"] == "ok", entry
    assert entry["rerun"].startswith(f"character file {folder / 'baseColor_1.png'} changed"), entry
    assert resume()["status"] == "skipped"
    with open(folder / "character.bin", "ab") as fh:  # the buffer edited
        fh.write(b"\0" * 16)
    entry = resume()
    assert entry["status"] == "ok" and f"character file {folder / 'character.bin'} changed" in entry["rerun"], entry


def test_every_file_option_is_stored_by_absolute_path(tmp_path, monkeypatch):
    """A rest take or face model given relative to the working folder is stored absolute,
    like the character: a resume from another folder compares the same files."""
    from capture2face.pipeline.options import options_json
    from capture2face.tracking import LandmarkerOptions, TrackOptions

    for name in ("rest.png", "rest.mp4", "model.task"):
        (tmp_path / name).write_bytes(b"x")
    monkeypatch.chdir(tmp_path)
    track = TrackOptions(neutral_image="rest.png", landmarker=LandmarkerOptions(face_model="model.task"))
    stored = options_json(RunOptions(track=track))
    assert stored["neutral_image"] == str(tmp_path / "rest.png")
    assert stored["face_model"] == str(tmp_path / "model.task")
    stored = options_json(RunOptions(track=TrackOptions(neutral_clip="rest.mp4")))
    assert stored["neutral_clip"] == str(tmp_path / "rest.mp4")
    assert options_json(RunOptions(track=TrackOptions(neutral_clip="gone.mp4")))["neutral_clip"] == "gone.mp4"

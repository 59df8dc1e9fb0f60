"""``capture2face batch``: parallel clips, failures isolated, resume, report, Ray."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from capture2face.batch import expand_inputs
from capture2face.errors import CaptureError

ENV = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
OUTPUTS = {"avatar.mp4", "compare.mp4", "track.npz", "animation.npz", "animation.glb", "livelink.csv", "report.html",
           "report.json"}


def test_inputs_expand_from_folders_globs_and_lists(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    for p in [a / "take.mp4", a / "x.MOV", a / "notes.txt", b / "take.mp4", b / "y.mkv"]:
        p.write_bytes(b"x")
    (tmp_path / "list.txt").write_text("# clips\nb/y.mkv\n\nb/take.mp4  # again\n")
    clips = expand_inputs([a, str(b / "*.mkv"), tmp_path / "list.txt", tmp_path / "gone.mp4"])
    got = [(Path(c.path).relative_to(tmp_path).as_posix() if Path(c.path).is_absolute() else c.path, c.name)
           for c in clips]
    # Folder: videos only, sorted; duplicates dropped; shared stems disambiguated; a
    # missing path is kept so that the batch reports it.
    assert [name for _, name in got] == ["a_take", "x", "y", "b_take", "gone"]
    with pytest.raises(CaptureError):
        expand_inputs([str(tmp_path / "*.webm")])
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(CaptureError):
        expand_inputs([empty])


@pytest.fixture(scope="module")
def clip_folder(sample_clip, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("batch_in")
    os.symlink(sample_clip, folder / "good.mp4")
    (folder / "bad.mp4").write_text("not a video at all\n")
    return folder


def _batch(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capture2face", "-q", "batch", *args], capture_output=True,
                          text=True, timeout=900, env=ENV)


@pytest.mark.slow
def test_batch_isolates_failures_and_resumes(clip_folder, tmp_path):
    out = tmp_path / "out"
    result = _batch(str(clip_folder), "-o", str(out), "--size", "128", "--jobs", "2")
    assert result.returncode == 1, result.stderr[-3000:]  # one clip failed
    report = json.loads((out / "batch_report.json").read_text())
    status = {Path(c["path"]).name: c for c in report["clips"]}
    assert status["good.mp4"]["status"] == "ok" and status["good.mp4"]["error"] is None
    assert status["good.mp4"]["seconds"] > 0
    assert status["bad.mp4"]["status"] == "failed" and "not a video" in status["bad.mp4"]["error"]
    assert report["summary"] == {"ok": 1, "failed": 1, "skipped": 0, "pending": 0}
    assert {p.name for p in (out / "good").iterdir()} == OUTPUTS
    assert not (out / "bad").exists()
    assert sorted(p.name for p in out.iterdir()) == ["batch_report.json", "good"]
    stamp = (out / "good" / "avatar.mp4").stat().st_mtime_ns

    result = _batch(str(clip_folder), "-o", str(out), "--size", "128", "--resume")
    assert result.returncode == 1, result.stderr[-3000:]
    report = json.loads((out / "batch_report.json").read_text())
    status = {Path(c["path"]).name: c["status"] for c in report["clips"]}
    assert status == {"good.mp4": "skipped", "bad.mp4": "failed"}
    assert (out / "good" / "avatar.mp4").stat().st_mtime_ns == stamp  # not redone


def test_resume_redoes_an_incomplete_output(tmp_path):
    from capture2face.pipeline import outputs_complete

    folder = tmp_path / "clip"
    folder.mkdir()
    names = sorted(OUTPUTS)
    for n in names:
        (folder / n).write_text("x")
    (folder / "report.json").write_text(json.dumps({"outputs": names}))
    assert outputs_complete(folder)
    (folder / "livelink.csv").unlink()
    assert not outputs_complete(folder)
    (folder / "livelink.csv").write_text("")
    assert not outputs_complete(folder)  # an empty file is not an output
    (folder / "livelink.csv").write_text("x")
    (folder / "report.json").write_text("{trunc")
    assert not outputs_complete(folder)


@pytest.mark.slow
def test_batch_on_a_local_ray_instance(clip_folder, tmp_path):
    pytest.importorskip("ray")
    from capture2face.batch import run_batch
    from capture2face.pipeline import RunOptions

    out = tmp_path / "out"
    report = run_batch([clip_folder], out, RunOptions(size=128, compare=False), ray_address="local", progress=False)
    status = {Path(c["path"]).name: c["status"] for c in report["clips"]}
    assert status == {"good.mp4": "ok", "bad.mp4": "failed"}
    assert {p.name for p in (out / "good").iterdir()} == OUTPUTS - {"compare.mp4"}
    assert json.loads((out / "batch_report.json").read_text())["summary"]["ok"] == 1


def test_batch_imports_a_glb_character_once(tmp_path, monkeypatch):
    """Two clips with an ARKit .glb character, one process: the batch's check and both
    clips share one import, so the automatic wrinkles (2-6 s) are built once; a changed
    file is imported again."""
    from capture2face.batch import run_batch
    from capture2face.character import load
    from capture2face.gltf.arkit_export import export_arkit_character
    from capture2face.pipeline import RunOptions, load_character
    from capture2face.rig.arkit_names import is_automatic
    from capture2face.rig.avatar import default_avatar
    from capture2face.synth import SynthOptions, synthesize

    clip = tmp_path / "a.mp4"
    synthesize(clip, SynthOptions(frames=8, size=128, seed=3, expression=False), progress=False)
    shutil.copyfile(clip, tmp_path / "b.mp4")  # a copy: a link to the same file is one clip
    char = tmp_path / "char.glb"
    export_arkit_character(default_avatar(), char, naming=".L")
    built = []
    real = load.automatic_wrinkles
    monkeypatch.setattr(load, "automatic_wrinkles", lambda rig, *a, **k: built.append(1) or real(rig, *a, **k))
    monkeypatch.setattr(load, "_IMPORTED", {})
    monkeypatch.setenv("CAPTURE2FACE_CACHE", str(tmp_path / "cache"))  # no prepared copy from another run

    report = run_batch([clip, tmp_path / "b.mp4"], tmp_path / "out", RunOptions(character=char, size=64, compare=False),
                       jobs=1, progress=False)
    assert [c["status"] for c in report["clips"]] == ["ok", "ok"]
    assert len(built) == 1
    rig = load_character(char)
    assert len(built) == 1 and is_automatic(rig)  # the memo's rig, with its wrinkle influences
    assert load_character(char) is rig
    os.utime(char, ns=(char.stat().st_atime_ns, char.stat().st_mtime_ns + 10**9))
    assert load_character(char) is not rig and len(built) == 1  # touched, same content: the prepared copy
    export_arkit_character(default_avatar(), char, naming="_L")  # new content
    assert len(built) == 1 and load_character(char) is not rig and len(built) == 2

"""``capture2face batch``: parallel clips, failures isolated, resume, report, Ray."""

from __future__ import annotations

import json
import os
import shutil
import socket
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
    from capture2face.render import RenderOptions

    out = tmp_path / "out"
    report = run_batch([clip_folder], out, RunOptions(render=RenderOptions(size=128), compare=False),
                       ray_address="local", progress=False)
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
    from capture2face.render import RenderOptions
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

    report = run_batch([clip, tmp_path / "b.mp4"], tmp_path / "out",
                       RunOptions(character=char, render=RenderOptions(size=64), compare=False), jobs=1, progress=False)
    assert [c["status"] for c in report["clips"]] == ["ok", "ok"]
    assert len(built) == 1
    rig = load_character(char)
    assert len(built) == 1 and is_automatic(rig)  # the memo's rig, with its wrinkle influences
    assert load_character(char) is rig
    os.utime(char, ns=(char.stat().st_atime_ns, char.stat().st_mtime_ns + 10**9))
    assert load_character(char) is not rig and len(built) == 1  # touched, same content: the prepared copy
    export_arkit_character(default_avatar(), char, naming="_L")  # new content
    assert len(built) == 1 and load_character(char) is not rig and len(built) == 2


# ---- Ray addresses that lead nowhere (issue 24) -----------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _one_line(result: subprocess.CompletedProcess, *said: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("capture2face: error: "), result.stderr[-2000:]
    assert all(s in lines[0] for s in said), lines[0]


def test_ray_address_with_nothing_listening_is_one_line(sample_clip, tmp_path):
    pytest.importorskip("ray")
    address = f"127.0.0.1:{_free_port()}"
    out = tmp_path / "out"
    _one_line(_batch(str(sample_clip), "-o", str(out), "--ray", address), f"--ray {address}: cannot connect",
              "Connection refused")
    assert not out.exists()  # no batch_report.json: nothing was started


def test_ray_address_that_never_answers_gives_up(sample_clip, tmp_path):
    """Something listens but never speaks Ray: Ray would retry for minutes."""
    pytest.importorskip("ray")
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(8)
        address = f"127.0.0.1:{listener.getsockname()[1]}"
        out = tmp_path / "out"
        _one_line(_batch(str(sample_clip), "-o", str(out), "--ray", address),
                  f"--ray {address}: no Ray cluster answered within 10 s")
    assert not out.exists()


def test_ray_auto_without_a_cluster_names_our_flags(sample_clip, tmp_path):
    pytest.importorskip("ray")
    if os.environ.get("RAY_ADDRESS") or Path("/tmp/ray/ray_current_cluster").exists():
        pytest.skip("a Ray cluster may be running here")
    result = _batch(str(sample_clip), "-o", str(tmp_path / "out"), "--ray", "auto")
    _one_line(result, "--ray auto: no running Ray cluster", "--ray HOST:PORT")
    assert "--address" not in result.stderr


@pytest.mark.parametrize("jobs", ["0", "-1"])
def test_jobs_below_one_is_refused(sample_clip, tmp_path, jobs):
    _one_line(_batch(str(sample_clip), "-o", str(tmp_path / "out"), "--jobs", jobs),
              f"--jobs {jobs}: must be 1 or more")
    assert not (tmp_path / "out").exists()


# ---- --resume decides by content (issue 24) ---------------------------------------------
SAMPLE = Path(__file__).resolve().parents[1] / "sample_videos" / "sample.mp4"  # 120 frames, not sample_clip's 90


def _entry(out: Path) -> dict:
    (entry,) = json.loads((out / "batch_report.json").read_text())["clips"]
    return entry


@pytest.mark.slow
def test_resume_reruns_a_clip_or_character_replaced_at_the_same_path(sample_clip, tmp_path):
    from capture2face.rig.avatar import default_avatar

    clip, hero, out = tmp_path / "take.mp4", tmp_path / "hero.npz", tmp_path / "out"
    shutil.copy(sample_clip, clip)
    default_avatar().save(hero)
    args = [str(clip), "-o", str(out), "--size", "128", "--no-audio", "--jobs", "1", "--character", str(hero)]
    assert _batch(*args).returncode == 0
    stored = json.loads((out / "take" / "report.json").read_text())["inputs"]
    assert stored["clip"]["size"] == clip.stat().st_size and stored["character"]["path"] == str(hero)
    assert _batch(*args, "--resume").returncode == 0
    assert _entry(out)["status"] == "skipped"

    shutil.copy(SAMPLE, clip)  # other content, same path
    assert _batch(*args, "--resume").returncode == 0
    entry = _entry(out)
    assert entry["status"] == "ok" and entry["frames"] == 120, entry
    assert entry["rerun"].startswith(f"clip {clip} changed (size ") and "content" in entry["rerun"], entry
    assert json.loads((out / "take" / "report.json").read_text())["frames"] == 120

    default_avatar(variant="wide").save(hero)  # the character replaced
    assert _batch(*args, "--resume").returncode == 0
    entry = _entry(out)
    assert entry["status"] == "ok" and entry["rerun"].startswith(f"character {hero} changed"), entry
    assert _batch(*args, "--resume").returncode == 0
    assert _entry(out)["status"] == "skipped"


def test_fingerprint_reads_the_first_and_last_mib(tmp_path):
    from capture2face.io.fingerprint import changes, fingerprint

    f = tmp_path / "big.bin"
    data = bytearray(os.urandom(3 << 20))
    f.write_bytes(bytes(data))
    before = fingerprint(f)
    data[(3 << 20) - 10] ^= 1  # in the last MiB
    f.write_bytes(bytes(data))
    os.utime(f, ns=(before["mtime_ns"], before["mtime_ns"]))
    assert changes(before, fingerprint(f)) == ["content"]
    data[-10] ^= 1
    data[(3 << 19)] ^= 1  # the middle is not read: the modification time tells
    f.write_bytes(bytes(data))
    assert changes(before, fingerprint(f)) == ["modification time"]
    assert changes(before, None) == ["gone"] and changes(None, before) == ["new"] and changes(None, None) == []
    assert changes(before, before) == []

"""Issue 15: a run never loses a user's file. Only a run's own files in ``OUT/<stem>/`` are
replaced (the manifest: report.json's outputs), the source clip is never touched, stale
staging folders of killed runs are removed, every OSError is one line with exit code 2,
and a damaged clip is recognised by a typed signal, not by a warning's words."""

from __future__ import annotations

import errno
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from capture2face.errors import CaptureError
from capture2face.io import staging
from capture2face.io.staging import JOURNAL, OWNER_FILE, check_output_folder, clean_stale_staging, staged_folder
from capture2face.render import RenderOptions
from tests.helpers import truncated_copy

KNOWN = ("avatar.mp4", "compare.mp4", "track.npz", "report.json")
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def _stage(final: Path, files: dict[str, str], protect=()) -> None:
    """One fake run: ``files`` (name -> text) staged and moved into ``final``; report.json
    lists them as the outputs."""
    with staged_folder(final, KNOWN, protect=protect) as tmp:
        for name, text in files.items():
            (tmp / name).write_text(text)
        (tmp / "report.json").write_text(json.dumps({"outputs": sorted(files)}))


def _staging_left(out: Path) -> list[str]:
    return sorted(p.name for p in out.glob(".tmp-*"))


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ---- the output folder (staging alone, fast) ---------------------------------------------
def test_user_files_and_source_clip_survive(tmp_path):
    final = tmp_path / "proj" / "d19"
    final.mkdir(parents=True)
    (final / "notes.txt").write_text("my notes")
    (final / "d19.mp4").write_bytes(b"the source clip")
    _stage(final, {"avatar.mp4": "a1", "compare.mp4": "c1"}, protect=[final / "d19.mp4"])
    assert (final / "notes.txt").read_text() == "my notes"
    assert (final / "d19.mp4").read_bytes() == b"the source clip"
    assert (final / "avatar.mp4").read_text() == "a1"
    assert sorted(p.name for p in final.iterdir()) == ["avatar.mp4", "compare.mp4", "d19.mp4", "notes.txt",
                                                       "report.json"]
    assert _staging_left(final.parent) == []


def test_rerun_replaces_exactly_its_own_files(tmp_path):
    final = tmp_path / "out" / "clip"
    _stage(final, {"avatar.mp4": "a1", "compare.mp4": "c1", "track.npz": "t1"})
    (final / "notes.txt").write_text("mine")
    notes_stat = (final / "notes.txt").stat()
    _stage(final, {"avatar.mp4": "a2", "track.npz": "t2"})  # compare off this time
    assert sorted(p.name for p in final.iterdir()) == ["avatar.mp4", "notes.txt", "report.json", "track.npz"]
    assert (final / "avatar.mp4").read_text() == "a2" and (final / "track.npz").read_text() == "t2"
    assert (final / "notes.txt").stat().st_mtime_ns == notes_stat.st_mtime_ns
    assert json.loads((final / "report.json").read_text())["outputs"] == ["avatar.mp4", "track.npz"]


def test_a_file_no_run_wrote_is_never_overwritten(tmp_path):
    final = tmp_path / "out" / "clip"
    final.mkdir(parents=True)
    (final / "avatar.mp4").write_text("the user's own video")
    with pytest.raises(CaptureError, match="no earlier run wrote it"):
        check_output_folder(final, ["avatar.mp4"], KNOWN)
    with pytest.raises(CaptureError, match="no earlier run wrote it"):
        _stage(final, {"avatar.mp4": "a1"})
    assert (final / "avatar.mp4").read_text() == "the user's own video"
    assert sorted(p.name for p in final.iterdir()) == ["avatar.mp4"]
    assert _staging_left(final.parent) == []


def test_source_clip_named_like_an_output_is_never_touched(tmp_path):
    final = tmp_path / "out" / "avatar"
    _stage(final, {"avatar.mp4": "a1", "compare.mp4": "c1"})
    clip = final / "compare.mp4"  # even one a run's manifest lists
    clip.write_bytes(b"the source clip")
    # not written over ...
    with pytest.raises(CaptureError, match="source clip would be overwritten"):
        _stage(final, {"avatar.mp4": "a2", "compare.mp4": "c2"}, protect=[clip])
    assert clip.read_bytes() == b"the source clip" and (final / "avatar.mp4").read_text() == "a1"
    # ... nor removed as a stale output
    _stage(final, {"avatar.mp4": "a2"}, protect=[clip])
    assert clip.read_bytes() == b"the source clip" and (final / "avatar.mp4").read_text() == "a2"


def test_a_crash_between_renames_leaves_an_incomplete_folder_the_next_run_replaces(tmp_path, monkeypatch):
    from capture2face.pipeline import outputs_complete

    final = tmp_path / "out" / "clip"
    (final.parent).mkdir()
    _stage(final, {"avatar.mp4": "a1", "compare.mp4": "c1"})
    (final / "notes.txt").write_text("mine")
    assert outputs_complete(final)
    real_replace, calls = os.replace, []

    def crash_after_one(src, dst):
        if calls and Path(dst).parent == final:
            raise KeyboardInterrupt  # SIGINT in the middle of the commit
        calls.append(dst)
        return real_replace(src, dst)

    monkeypatch.setattr(staging.os, "replace", crash_after_one)
    with pytest.raises(KeyboardInterrupt):
        _stage(final, {"avatar.mp4": "a2", "track.npz": "t2"})
    monkeypatch.setattr(staging.os, "replace", real_replace)
    assert not outputs_complete(final)  # report.json went first
    assert (final / JOURNAL).is_file() and (final / "notes.txt").read_text() == "mine"
    assert _staging_left(final.parent) == []
    _stage(final, {"avatar.mp4": "a3", "track.npz": "t3"})
    assert sorted(p.name for p in final.iterdir()) == ["avatar.mp4", "notes.txt", "report.json", "track.npz"]
    assert outputs_complete(final)


def test_write_failure_leaves_nothing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(OSError), staged_folder(out / "clip", KNOWN) as tmp:
        (tmp / "avatar.mp4").write_text("half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp / "track.npz"))
    assert not out.exists()


# ---- stale staging folders ----------------------------------------------------------------
def _fake_staging(out: Path, name: str, pid: int | None, started: float) -> Path:
    d = out / f".tmp-{name}"
    (d / ".work").mkdir(parents=True)
    (d / ".work" / "landmarks.f32").write_bytes(b"\0" * 1000)
    if pid is not None:
        (d / OWNER_FILE).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "started": started}))
    return d


def test_stale_staging_of_a_killed_run_is_removed_with_a_warning(tmp_path, caplog):
    out = tmp_path / "out"
    now = time.time()
    dead = _fake_staging(out, "a-dead", _dead_pid(), now - 60)
    live = _fake_staging(out, "b-live", os.getpid(), now - 60)  # a run still going
    young = _fake_staging(out, "c-unowned", None, now)  # no owner, just touched: maybe live
    old = _fake_staging(out, "d-unowned-old", None, now)
    for p in [old, *old.rglob("*")]:
        os.utime(p, (now - 2 * 3600, now - 2 * 3600))
    with caplog.at_level("WARNING", logger="capture2face"):
        _stage(out / "clip", {"avatar.mp4": "a1"})
    assert not dead.exists() and not old.exists()
    assert live.exists() and young.exists()
    assert "removed 2 staging folder(s)" in caplog.text and dead.name in caplog.text and old.name in caplog.text
    assert clean_stale_staging(out) == []


# ---- typed damage signal ------------------------------------------------------------------
def test_damage_is_a_typed_event(sample_clip, tmp_path):
    from capture2face.io.video_input import ClipDamage, iter_frames, watch_damage

    cut = truncated_copy(sample_clip, tmp_path)
    with watch_damage(sample_clip) as other, watch_damage(cut) as damage:
        n = sum(1 for _ in iter_frames(cut))
    assert other == []
    assert len(damage) >= 1 and isinstance(damage[0], ClipDamage)
    assert damage[0].frames_decoded == n and damage[0].path == str(cut)


def test_damage_decision_does_not_read_warning_text(sample_clip, tmp_path, monkeypatch):
    """A damage event fails the run whatever its words; without one, no warning text does."""
    from capture2face import pipeline
    from capture2face.io.video_input import ClipDamage, _report_damage
    from capture2face.pipeline import runner

    def damaged_track(clip, options, progress=True, workdir=None, workers=None, info=None):
        _report_damage(ClipDamage(str(clip), 3, 90, "decode_error", "frames lost after frame 3"))
        raise RuntimeError("tracking broke on the damage")

    monkeypatch.setattr(runner, "track_stage", damaged_track)
    with pytest.raises(CaptureError, match="^frames lost after frame 3$"):
        pipeline.run(sample_clip, tmp_path / "out", pipeline.RunOptions(compare=False, render=RenderOptions(size=64)),
                     progress=False)
    assert not (tmp_path / "out").exists() or list((tmp_path / "out").iterdir()) == []


# ---- whole runs ------------------------------------------------------------------------
@pytest.mark.slow
def test_run_keeps_user_files_and_replaces_only_its_own(sample_clip, tmp_path, monkeypatch, caplog):
    from capture2face import pipeline
    from capture2face.pipeline import runner
    from capture2face.runtime.log import log

    proj = tmp_path / "proj"
    folder = proj / "d19"
    folder.mkdir(parents=True)
    clip = folder / "d19.mp4"
    shutil.copy(sample_clip, clip)
    (folder / "notes.txt").write_text("take 3 was the good one")
    clip_bytes, clip_mtime = clip.read_bytes(), clip.stat().st_mtime_ns
    real_track = runner.track_stage

    def track_with_a_truncated_word(*args, **kwargs):
        log.warning("the word truncated in a warning decides nothing")
        return real_track(*args, **kwargs)

    monkeypatch.setattr(runner, "track_stage", track_with_a_truncated_word)
    report = pipeline.run(clip, proj, pipeline.RunOptions(render=RenderOptions(size=64)), progress=False)
    monkeypatch.setattr(runner, "track_stage", real_track)
    assert any("truncated" in w for w in report["warnings"])
    assert "compare.mp4" in report["outputs"]
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted([*report["outputs"], "d19.mp4", "notes.txt"])
    assert pipeline.outputs_complete(folder)
    avatar_inode = (folder / "avatar.mp4").stat().st_ino

    # a killed run's staging folder, then a rerun without compare
    stale = proj / ".tmp-d19-killed"
    (stale / ".work").mkdir(parents=True)
    (stale / "track.npz").write_bytes(b"\0" * 4096)
    (stale / OWNER_FILE).write_text(json.dumps({"pid": _dead_pid(), "host": socket.gethostname(),
                                                "started": time.time() - 5}))
    report2 = pipeline.run(clip, proj, pipeline.RunOptions(render=RenderOptions(size=64), compare=False),
                           progress=False)
    assert not stale.exists()
    assert any("staging folder" in w and stale.name in w for w in report2["warnings"])
    assert "compare.mp4" not in report2["outputs"]
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted([*report2["outputs"], "d19.mp4", "notes.txt"])  # compare.mp4 removed
    assert (folder / "avatar.mp4").stat().st_ino != avatar_inode  # replaced
    assert clip.read_bytes() == clip_bytes and clip.stat().st_mtime_ns == clip_mtime
    assert (folder / "notes.txt").read_text() == "take 3 was the good one"
    assert _staging_left(proj) == [] and not (folder / JOURNAL).exists()
    assert pipeline.outputs_complete(folder)


# ---- OSError at the command line ------------------------------------------------------------
ENOSPC_RUN = """
import errno, os, sys
from capture2face.pipeline import runner
real = runner.export_stage
def export_stage(rig, animation, folder, track=None, **kw):
    real(rig, animation, folder, track, **kw)
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.path.join(folder, "livelink.csv"))
runner.export_stage = export_stage
from capture2face.cli import main
raise SystemExit(main(sys.argv[1:]))
"""


def _one_line_error(result, text: str) -> None:
    assert result.returncode == 2, result.stderr[-2000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr[-2000:]
    assert lines[0].startswith("capture2face: error: ") and text in lines[0]
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_disk_full_mid_run_is_one_line_and_leaves_nothing(sample_clip, tmp_path):
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-c", ENOSPC_RUN, "-q", "run", str(sample_clip), "-o", str(out),
                             "--size", "64"], capture_output=True, text=True, env=ENV, timeout=600)
    _one_line_error(result, "livelink.csv: No space left on device")
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == []


def test_os_error_line():
    from capture2face.cli import os_error_line

    assert os_error_line(OSError(errno.ENOSPC, "No space left on device", "/o/x.mp4")) == \
        "/o/x.mp4: No space left on device"
    assert os_error_line(OSError(errno.EXDEV, "Invalid cross-device link", "/a", None, "/b")) == \
        "/a -> /b: Invalid cross-device link"
    assert os_error_line(OSError("disk\non fire")) == "disk on fire"


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 1 MB tmpfs (root only; skipped where mounting is not permitted)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs: {done.stderr.decode(errors='replace').strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


@pytest.mark.slow
def test_real_full_disk_is_one_line_and_leaves_nothing(sample_clip, small_tmpfs):
    out = small_tmpfs / "out"
    result = subprocess.run([sys.executable, "-m", "capture2face", "-q", "run", str(sample_clip), "-o", str(out),
                             "--size", "256"], capture_output=True, text=True, env=ENV, timeout=600)
    _one_line_error(result, ": No space left on device")
    assert str(out) in result.stderr  # the path: the output folder at least
    assert sorted(p.relative_to(small_tmpfs).as_posix() for p in small_tmpfs.rglob("*")) == []


# ---- two runs, one output folder (issue 24) ------------------------------------------------
def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capture2face", "-q", *args], capture_output=True, text=True,
                          env=ENV, timeout=600, check=False)


@pytest.mark.slow
def test_same_named_clips_from_two_folders_do_not_replace_each_other(sample_clip, tmp_path):
    (tmp_path / "day1").mkdir()
    (tmp_path / "day2").mkdir()
    shutil.copy(sample_clip, tmp_path / "day1" / "take.mp4")
    shutil.copy(Path(__file__).resolve().parents[1] / "sample_videos" / "sample.mp4", tmp_path / "day2" / "take.mp4")
    out = tmp_path / "out"
    args = ["-o", str(out), "--size", "128", "--no-audio"]
    assert _cli("run", str(tmp_path / "day1" / "take.mp4"), *args).returncode == 0
    before = {p.name: p.stat().st_mtime_ns for p in (out / "take").iterdir()}
    result = _cli("run", str(tmp_path / "day2" / "take.mp4"), *args)
    _one_line_error(result, f"{out / 'take'} holds the outputs of another clip, {tmp_path / 'day1' / 'take.mp4'}")
    assert {p.name: p.stat().st_mtime_ns for p in (out / "take").iterdir()} == before  # untouched
    assert sorted(p.name for p in out.iterdir()) == ["take"]
    # The same clip again replaces its own outputs; the other one goes beside it by name.
    assert _cli("run", str(tmp_path / "day1" / "take.mp4"), *args).returncode == 0
    assert _cli("run", str(tmp_path / "day2" / "take.mp4"), *args, "--name", "day2_take").returncode == 0
    assert json.loads((out / "day2_take" / "report.json").read_text())["frames"] == 120
    assert json.loads((out / "take" / "report.json").read_text())["frames"] == 90
    assert sorted(p.name for p in out.iterdir()) == ["day2_take", "take"]


def test_a_second_run_into_a_folder_being_written_is_refused(sample_clip, tmp_path):
    """Another run holds OUT/<name> (its lock): a run into it fails at once in one line
    instead of losing its work (or the other run's) at the end."""
    out = tmp_path / "out"
    out.mkdir()
    lock = staging.lock_output(out / "synth_clip")
    try:
        result = _cli("run", str(sample_clip), "-o", str(out), "--size", "64")
        _one_line_error(result, f"{out / 'synth_clip'}: another run is writing there (pid {os.getpid()} on ")
        assert sorted(p.name for p in out.iterdir()) == [".capture2face-synth_clip.lock"]  # nothing of its own
        with pytest.raises(CaptureError, match="another run is writing there"):
            _stage(out / "synth_clip", {"avatar.mp4": "x"})
    finally:
        staging.unlock_output(lock)
    assert list(out.iterdir()) == []  # released: the lock file goes with it
    _stage(out / "synth_clip", {"avatar.mp4": "x"})
    assert sorted(p.name for p in out.iterdir()) == ["synth_clip"]


def test_a_lock_file_left_by_a_killed_run_does_not_block(tmp_path):
    staging.lock_path(tmp_path / "clip").write_text('{"pid": 1, "host": "x", "started": 0}\n')  # nobody holds it
    _stage(tmp_path / "clip", {"avatar.mp4": "x"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip"]

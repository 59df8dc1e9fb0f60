"""Bad input through the command line: exit code 2, one clear line on stderr, no
traceback, and nothing left in the output folder. Interrupts leave nothing behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import truncated_copy, write_video

ENV = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2", PYTHONUNBUFFERED="1")


def cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capture2face", *args], capture_output=True,
                          text=True, timeout=timeout, env=ENV)


def write_audio_only(path: Path) -> Path:
    import av

    with av.open(str(path), "w") as c:
        s = c.add_stream("aac", rate=44100)
        s.layout = "mono"
        t = np.arange(22050) / 44100
        for i in range(0, len(t), 1024):
            chunk = (0.3 * np.sin(2 * np.pi * 440 * t[i:i + 1024]))[None].astype(np.float32)
            frame = av.AudioFrame.from_ndarray(chunk, format="fltp", layout="mono")
            frame.sample_rate = 44100
            for p in s.encode(frame):
                c.mux(p)
        for p in s.encode(None):
            c.mux(p)
    return path


def write_zero_frames(path: Path) -> Path:
    """An .mp4 whose video stream exists but holds no frame (fragmented mp4 writes the
    track header up front; a plain mp4 would drop the empty track)."""
    import av

    with av.open(str(path), "w", options={"movflags": "frag_keyframe+empty_moov"}) as c:
        s = c.add_stream("libx264", rate=25)
        s.width = s.height = 64
        s.pix_fmt = "yuv420p"
        c.start_encoding()
    return path


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bad_inputs")
    faceless = write_video(d / "noface.mp4", 20)
    truncated = d / "truncated.mp4"
    data = write_video(d / "full.mp4", 40, seed=1).read_bytes()
    truncated.write_bytes(data[: len(data) // 2])  # moov sits at the end: the index is gone
    # With the index up front ("faststart"), the first frames decode and the rest is gone.
    data = write_video(d / "faststart.mp4", 40, seed=1, movflags="faststart").read_bytes()
    (d / "truncated_tail.mp4").write_bytes(data[: len(data) * 6 // 10])
    (d / "empty.mp4").write_bytes(b"")
    (d / "text.mp4").write_text("this is not a video\n" * 20)
    (d / "folder.mp4").mkdir()
    (d / "corrupt.npz").write_bytes(os.urandom(2048))
    (d / "corrupt.glb").write_bytes(b"glTF" + os.urandom(400))
    return {
        "noface": faceless, "truncated": truncated, "truncated_tail": d / "truncated_tail.mp4",
        "empty": d / "empty.mp4", "text": d / "text.mp4",
        "folder": d / "folder.mp4", "audio": write_audio_only(d / "audio.mp4"),
        "zero": write_zero_frames(d / "zero.mp4"), "missing": d / "missing.mp4",
        "corrupt_npz": d / "corrupt.npz", "corrupt_glb": d / "corrupt.glb",
    }


def assert_clean_failure(result: subprocess.CompletedProcess, out: Path, must_mention: str,
                         path: Path | None = None) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, result.stderr[-2000:]
    assert lines[0].startswith("capture2face: error: "), lines[0]
    reason = lines[0].replace(str(path), "<path>") if path is not None else lines[0]
    assert must_mention.lower() in reason.lower(), lines[0]
    assert "Traceback" not in result.stderr
    assert not out.exists() or not any(out.iterdir()), sorted(p.name for p in out.rglob("*"))


@pytest.mark.parametrize("case,mention", [
    ("missing", "no such file"),
    ("folder", "directory"),
    ("empty", "empty"),
    ("text", "not a video"),
    ("truncated", "not a video"),  # the index (moov, at the end) is cut off
    ("truncated_tail", "truncated"),
    ("audio", "no video stream"),
    ("zero", "no frames"),
])
def test_unreadable_clip_fails_cleanly(inputs, tmp_path, case, mention):
    out = tmp_path / "out"
    assert_clean_failure(cli("-q", "run", str(inputs[case]), "-o", str(out)), out, mention, inputs[case])


@pytest.mark.slow
def test_clip_without_a_face_fails_cleanly(inputs, tmp_path):
    out = tmp_path / "out"
    result = cli("-q", "run", str(inputs["noface"]), "-o", str(out), "--size", "128")
    assert_clean_failure(result, out, "no face")


@pytest.mark.parametrize("case", ["corrupt_npz", "corrupt_glb"])
def test_corrupt_character_fails_cleanly(inputs, tmp_path, case):
    out = tmp_path / "out"
    result = cli("-q", "run", str(inputs["noface"]), "-o", str(out), "--character", str(inputs[case]))
    assert_clean_failure(result, out, inputs[case].name)


def test_missing_character_fails_cleanly(inputs, tmp_path):
    out = tmp_path / "out"
    result = cli("-q", "run", str(inputs["noface"]), "-o", str(out), "--character", str(tmp_path / "nobody.glb"))
    assert_clean_failure(result, out, "no such file")


def test_output_path_that_is_a_file_fails_cleanly(inputs, tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file where the output folder should go")
    result = cli("-q", "run", str(inputs["noface"]), "-o", str(blocker / "out"))
    assert_clean_failure(result, blocker.parent / "nothing-here", "cannot write")
    assert blocker.read_text().startswith("a file")


def test_unwritable_output_folder_fails_cleanly(inputs, tmp_path):
    if os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o555)
        out = locked / "out"
    elif _sysfs_readonly():
        out = Path("/sys/capture2face-test-out")  # root may write anywhere but sysfs
    else:
        pytest.skip("running as root and no read-only folder to write into")
    try:
        result = cli("-q", "run", str(inputs["noface"]), "-o", str(out))
        assert_clean_failure(result, out, "cannot write")
    finally:
        if os.geteuid() != 0:
            (tmp_path / "locked").chmod(0o755)


def _sysfs_readonly() -> bool:
    try:
        os.mkdir("/sys/capture2face-probe")
    except OSError:
        return os.path.isdir("/sys")
    os.rmdir("/sys/capture2face-probe")
    return False


def test_debug_shows_the_traceback(inputs, tmp_path):
    result = cli("--debug", "-q", "run", str(inputs["text"]), "-o", str(tmp_path / "out"))
    assert result.returncode != 0
    assert "Traceback" in result.stderr and "CaptureError" in result.stderr


# ---- interrupts ---------------------------------------------------------------------------
def _wait_for(predicate, proc, timeout: float) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if predicate():
            return True
        if proc.poll() is not None:
            return False
        time.sleep(0.05)
    return False


def _staging(out: Path) -> list[Path]:
    return [p for p in out.glob(".tmp-*") if p.is_dir()] if out.exists() else []


@pytest.mark.slow
@pytest.mark.parametrize("sig,when", [(signal.SIGINT, "render"), (signal.SIGTERM, "track")])
def test_interrupted_run_leaves_nothing(sample_clip, tmp_path, sig, when):
    """SIGINT while rendering, SIGTERM while tracking: exit 130, no file left behind."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "capture2face", "-q", "run", str(sample_clip), "-o", str(out),
                             "--size", "256"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        if when == "track":
            reached = _wait_for(lambda: bool(_staging(out)), proc, 120)
        else:  # track.npz is written before rendering starts
            reached = _wait_for(lambda: any((d / "track.npz").exists() for d in _staging(out)), proc, 180)
        assert reached, "the run ended before the interrupt point"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted" in err and "Traceback" not in err
    left = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
    assert left == [], left


@pytest.mark.slow
def test_truncated_clip_can_be_salvaged_on_request(sample_clip, tmp_path):
    """``allow_truncated``: the frames before the damage are processed, with a warning."""
    import av

    from capture2face.pipeline import RunOptions, run
    from capture2face.render import RenderOptions

    cut = truncated_copy(sample_clip, tmp_path)
    report = run(cut, tmp_path / "out",
                 RunOptions(render=RenderOptions(size=128), compare=False, allow_truncated=True), progress=False)
    assert 10 < report["frames"] < 90
    assert any("truncated" in w for w in report["warnings"])
    with av.open(str(tmp_path / "out" / "cut" / "avatar.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == report["frames"]


INTERRUPT_IN_EXEC = """
import sys
from capture2face import cli
def interrupted(args):  # as if the signal landed while a dataclass was being defined
    exec("raise KeyboardInterrupt")
cli._cmd_avatar = interrupted
sys.argv = ["capture2face", "avatar"]
raise SystemExit(cli.main())
"""


def test_an_interrupt_inside_an_exec_still_exits_130(tmp_path):
    """Run as ``python -m`` (as the tests and users run it), CPython ends a process by
    SIGINT once a KeyboardInterrupt has left an exec of a string, even a caught one; the
    command exits 130 all the same."""
    (tmp_path / "interrupt_in_exec.py").write_text(INTERRUPT_IN_EXEC)
    done = subprocess.run([sys.executable, "-m", "interrupt_in_exec"], capture_output=True, text=True, env=ENV,
                          cwd=tmp_path, timeout=120)
    assert done.returncode == 130, (done.returncode, done.stderr[-2000:])
    assert done.stderr.strip() == "capture2face: interrupted"


def test_an_interrupt_swallowed_by_a_finalizer_is_not_lost(monkeypatch):
    """A signal that lands in a weakref callback is dropped by Python ("Exception ignored");
    the handler's flag makes the next stage boundary raise it again, and the ignored
    exception is not printed as a traceback."""
    import gc
    import weakref

    from capture2face import errors

    monkeypatch.setattr(errors, "_interrupted", False)
    errors.raise_if_interrupted()  # nothing pending: no-op

    class Thing:
        pass

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", errors._unraisable)
    monkeypatch.setattr(sys, "__unraisablehook__", lambda info: seen.append(info))
    thing = Thing()
    weakref.finalize(thing, errors._raise_interrupt, signal.SIGINT, None)
    del thing
    gc.collect()
    assert seen == []  # swallowed quietly ...
    with pytest.raises(KeyboardInterrupt):  # ... but remembered
        errors.raise_if_interrupted()


def test_a_finalizer_broken_by_the_interrupt_prints_nothing(monkeypatch):
    """An interrupt that cuts an object's construction short leaves a finalizer that fails
    (MediaPipe's ``Image.__del__``: no ``_image_ptr``); after the interrupt that is not printed,
    before it a finalizer's error still is."""
    import gc
    import sys
    import weakref

    from capture2face import errors

    def broken():
        raise AttributeError("'Image' object has no attribute '_image_ptr'")

    seen = []
    monkeypatch.setattr(sys, "unraisablehook", errors._unraisable)
    monkeypatch.setattr(sys, "__unraisablehook__", lambda info: seen.append(info))
    for interrupted in (False, True):
        monkeypatch.setattr(errors, "_interrupted", interrupted)

        class Half:
            pass

        half = Half()
        weakref.finalize(half, broken)
        del half
        gc.collect()
    assert len(seen) == 1 and isinstance(seen[0].exc_value, AttributeError)


# ---- a mapping JSON beside the character ------------------------------------------------
JUNK_MAPPINGS = [
    ('{"scale": "big"}', "scale must be a number > 0, not 'big'"),
    ('{"scale": null}', "scale must be a number > 0, not null"),
    ('{"bones": [1]}', "bones must be an object, not list"),
    ('{"bones": {"X": "a"}}', "bones['X'] must be a landmark index 0..477, not 'a'"),
    ('{"landmark_vertices": [1, 2, 3]}', "landmark_vertices must be an object"),
    ('{"landmark_vertices": {"a": 1}}', "landmark_vertices key 'a' must be a landmark index"),
    ('{"poses": []}', "poses must be an object"),
    ('{"poses": {"stretch": 5}}', "poses['stretch'] must be an object"),
    ('{"wrinkle_maps": 3}', "wrinkle_maps must be an object, not 3"),
    ('{"wrinkle_maps": {"stretch": 5}}', "wrinkle_maps['stretch'] must be a string, not 5"),
    ('{"zone_table": 3}', "zone_table must be an object, not 3"),
    ('{"zone_table": {"browInnerUp": [0, 0, "a", 0, 0, 0, 0, 0]}}', "zone_table['browInnerUp'] must be a list of 8"),
    ('{"bone_groups": 5}', "bone_groups must be a list, not 5"),
    ('[1, 2]', "must be an object"),
]


@pytest.fixture(scope="module")
def arkit_glb(tmp_path_factory) -> Path:
    from capture2face.gltf.arkit_export import export_arkit_character
    from capture2face.rig.avatar import default_avatar

    path = tmp_path_factory.mktemp("arkit") / "hero.glb"
    export_arkit_character(default_avatar(), path)
    return path


@pytest.mark.parametrize("text,said", JUNK_MAPPINGS)
def test_junk_mapping_is_named_field_by_field(arkit_glb, tmp_path, text, said):
    from capture2face.character.load import load_character
    from capture2face.errors import CaptureError

    glb = tmp_path / "hero.glb"
    glb.write_bytes(arkit_glb.read_bytes())
    (tmp_path / "hero.json").write_text(text)
    with pytest.raises(CaptureError) as err:
        load_character(glb)
    line = str(err.value)
    assert "\n" not in line and str(tmp_path / "hero.json") in line and said in line, line
    assert "malformed glTF" not in line


def test_every_wrong_field_in_one_line(arkit_glb, tmp_path):
    from capture2face.gltf.mapping import mapping_errors

    errors = mapping_errors({"scale": -1, "bones": {"Jaw": 500, "Brow": 3}, "morphs": {"A": "notArkit"},
                             "zone_masks": ["a.png"], "materials": {"Eye": "glass"}, "name": "ok"})
    assert len(errors) == 5, errors
    assert mapping_errors({"name": "x", "scale": 100.0, "head_bone": "Head", "bones": {"Jaw": 152},
                           "bone_groups": [["Jaw"]], "landmark_vertices": {"33": 1043},
                           "materials": {"EyeMaterial": "eye", "Lashes": "hair"}, "wrinkle_maps": {"stretch": "s.png"},
                           "poses": {"stretch": {"offsets": {"Jaw": [0, 0.8, 0.1]}, "wrinkle_map": "stretch",
                                                 "morphs": {"browInnerUp": 1.0}},
                                     "compress": {"positions": {"Jaw": [1.1, 3.9, 5]}}},
                           "zone_masks": ["a.png", "b.png"], "zone_table": {"browInnerUp": [-1, -1, 0, 0, 0, 0, 0, 0]},
                           "morphs": {"Fcl_MTH_A": "jawOpen"}}) == []


def test_junk_mapping_fails_the_run_before_tracking(arkit_glb, sample_clip, tmp_path):
    (tmp_path / "hero.json").write_text('{"bones": {"X": "a"}, "scale": "big"}')
    glb = tmp_path / "hero.glb"
    glb.write_bytes(arkit_glb.read_bytes())
    out = tmp_path / "out"
    result = cli("run", str(sample_clip), "-o", str(out), "--character", str(glb), timeout=120)
    assert_clean_failure(result, out, "bones['X'] must be a landmark index")
    assert "scale must be a number" in result.stderr


# ---- file names that are not UTF-8 ------------------------------------------------------
def test_clip_name_not_utf8_runs_and_reports(sample_clip, tmp_path):
    """``café.mp4`` written in Latin-1 (the bytes ``caf\\xe9``): report.html, report.json and
    the printed line all name it, with the byte written as ``\\xe9``."""
    clip = Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9.mp4"))
    clip.write_bytes(sample_clip.read_bytes())
    out = tmp_path / "out"
    result = cli("-q", "run", str(clip), "-o", str(out), "--size", "128", "--no-audio")
    assert result.returncode == 0, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    folder = out / clip.stem
    assert "caf\\xe9" in result.stdout, result.stdout
    report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    assert os.fsencode(report["clip"]) == os.fsencode(clip)  # the surrogate escape round-trips
    page = (folder / "report.html").read_text(encoding="utf-8")  # valid UTF-8 throughout
    assert "caf\\xe9.mp4" in page


def test_batch_of_non_utf8_names_fails_on_stderr(tmp_path):
    """A bad clip with a Latin-1 name in a batch: its "failed" line on stderr with the
    byte escaped, batch_report.json written and readable."""
    bad = Path(os.fsdecode(bytes(tmp_path) + b"/na\xefve.mp4"))
    bad.write_text("not a video\n")
    (tmp_path / "list.txt").write_bytes(b"na\xefve.mp4\n")  # a list in Latin-1 names the same file
    out = tmp_path / "out"
    result = cli("-q", "batch", str(tmp_path / "list.txt"), "-o", str(out), "--jobs", "1")
    assert result.returncode == 1, result.stderr[-2000:]
    assert "Traceback" not in result.stderr
    assert "failed: " not in result.stdout
    failed = [ln for ln in result.stderr.splitlines() if ln.startswith("failed: ")]
    assert len(failed) == 1 and "na\\xefve.mp4" in failed[0] and "not a video" in failed[0], result.stderr
    report = json.loads((out / "batch_report.json").read_text(encoding="utf-8"))
    assert os.fsencode(report["clips"][0]["path"]) == os.fsencode(bad)


def test_readable_escapes_only_undecodable_bytes():
    from capture2face.io.paths import readable

    assert readable(os.fsdecode(b"caf\xe9-\xc3\xa9.mp4")) == "caf\\xe9-\u00e9.mp4"
    assert readable("plain") == "plain"

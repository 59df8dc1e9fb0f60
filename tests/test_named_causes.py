"""Issue 33 (items 4, 13, 14, 15): a failure names its real cause, in one line, exit 2,
before tracking wherever it can be known there.

* an existing ``OUT/<clip>`` folder that is read-only, or whose report.json cannot be read,
  is named as such before tracking (not a temporary file after rendering, not avatar.mp4);
* a folder given where a file is meant (``--neutral-image``, ``--neutral-clip``,
  ``--face-model``, ``$CAPTURE2FACE_FACE_MODEL``) says it is a folder;
* an image too large for FFmpeg says its size and the limit, not "truncated or corrupt";
* ``eval synthetic --actor`` with a character the tracker finds no face on names the
  actor, not the temporary video rendered of it;
* ``--name`` (and a clip's stem) that collides with a run's hidden lock or staging names,
  has a path separator, or is empty, '.', '..' or too long is refused;
* ``tools/mirror_identity.py`` never leaves a partial file and never overwrites its input.
"""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from capture2face import cli
from capture2face.gltf.container import ARRAY_BUFFER, GlbBuilder
from capture2face.io.video_input import _too_large, image_size
from tests.helpers import REPO, shared_character

SAMPLE = REPO / "sample_videos" / "sample.mp4"
MIRROR = REPO / "tools" / "mirror_identity.py"


def _main(capsys, *argv: str) -> str:
    """``capture2face -q ARGV`` in this process: exit 2 and one error line, the last on stderr
    (after any ``capture2face: warning:`` lines the run's own checks print)."""
    code = cli.main(["-q", *argv])
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if not ln.startswith("capture2face: warning: ")]
    assert code == 2 and errors == lines[-1:] and lines[-1].startswith("capture2face: error: "), (code, lines)
    assert "/.tmp-" not in lines[-1]  # never an internal temporary file
    return lines[-1]


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else b"<dir>")
            for p in sorted(folder.rglob("*"))}


# ---- item 4: a read-only OUT/<clip> fails before tracking, naming the folder ----------------------
def _deny_writes_to(folder: Path, monkeypatch) -> None:
    """``folder`` read-only: chmod, and where this process writes anyway (root bypasses
    permissions) ``os.access`` emulates it for the check."""
    folder.chmod(0o555)
    if os.access(folder, os.W_OK):
        real = os.access

        def access(path, mode, *args, **kwargs):
            if Path(path) == folder and mode & os.W_OK:
                return False
            return real(path, mode, *args, **kwargs)

        monkeypatch.setattr(os, "access", access)


def test_read_only_output_folder_fails_before_tracking_naming_it(tmp_path, no_tracking, capsys, monkeypatch):
    final = tmp_path / "out" / "sample"
    final.mkdir(parents=True)
    (final / "notes.txt").write_text("mine")
    _deny_writes_to(final, monkeypatch)
    try:
        line = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path / "out"))
    finally:
        final.chmod(0o755)
    assert f"cannot write to output folder {final}: it is read-only" in line
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["sample"]  # no lock, no staging
    assert _tree(final) == {"notes.txt": b"mine"}


@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("setpriv"), reason="needs root and setpriv")
def test_read_only_output_folder_for_real_without_root_s_override(tmp_path):
    """The same as a user without root's permission override (setpriv drops it): the
    folder's permissions are checked, not an emulation."""
    out = tmp_path / "out"
    (out / "sample").mkdir(parents=True)
    (out / "sample" / "notes.txt").write_text("mine")
    (out / "sample").chmod(0o555)
    env = dict(os.environ, PYTHONPATH=str(REPO), GLOG_minloglevel="2")
    done = subprocess.run(["setpriv", "--bounding-set", "-dac_override,-dac_read_search", sys.executable,
                           "-m", "capture2face", "-q", "run", str(SAMPLE), "-o", str(out)],
                          capture_output=True, text=True, timeout=300, env=env, check=False)
    (out / "sample").chmod(0o755)
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-2000:]
    assert f"cannot write to output folder {out / 'sample'}: it is read-only" in lines[0]
    assert _tree(out / "sample") == {"notes.txt": b"mine"}



@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("setpriv"), reason="needs root and setpriv")
@pytest.mark.parametrize("command", [["eval", "synthetic", "--frames", "60", "--size", "64"],
                                     ["eval", "fidelity", str(SAMPLE)]])
def test_a_json_into_a_read_only_folder_fails_first_naming_it(tmp_path, command):
    """``--json`` into a read-only folder: refused before the evaluation, naming the folder,
    never the temporary file beside the JSON."""
    folder = tmp_path / "figures"
    folder.mkdir()
    folder.chmod(0o555)
    env = dict(os.environ, PYTHONPATH=str(REPO), GLOG_minloglevel="2")
    done = subprocess.run(["setpriv", "--bounding-set", "-dac_override,-dac_read_search", sys.executable,
                           "-m", "capture2face", "-q", *command, "--json", str(folder / "f.json")],
                          capture_output=True, text=True, timeout=300, env=env, check=False)
    folder.chmod(0o755)
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-2000:]
    assert lines[0].startswith(f"capture2face: error: --json {folder / 'f.json'}: cannot write to output folder "
                               f"{folder}"), lines[0]
    assert ".tmp-" not in lines[0] and not any(folder.iterdir())


# ---- item 13: an unreadable report.json is named, not avatar.mp4 -----------------------------------
@pytest.mark.parametrize("report, said", [
    (b"\xff\xfe\x00garbage", "cannot be read (not UTF-8 text)"),
    (b'{"outputs": ["avatar.mp4"', "cannot be read (not valid JSON"),
    (b"[1, 2]", "is not a capture2face run's report"),
    (None, "cannot be read (Is a directory)"),
])
def test_unreadable_report_is_named_not_avatar_mp4(tmp_path, no_tracking, capsys, report, said):
    final = tmp_path / "out" / "sample"
    final.mkdir(parents=True)
    (final / "avatar.mp4").write_bytes(b"an earlier run's video")
    if report is None:
        (final / "report.json").mkdir()
    else:
        (final / "report.json").write_bytes(report)
    before = _tree(final)
    line = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path / "out"))
    assert f"{final / 'report.json'}: {said}" in line and "which files there an earlier run wrote" in line
    assert _tree(final) == before



@pytest.mark.parametrize("report, said", [
    (b"", "not valid JSON"),
    (b"\xff\xfe\x00garbage", "not UTF-8 text"),
    (b"[1, 2]", "not a capture2face run's report"),
    (b'{"options": []}', "not a capture2face run's report"),
    (None, "Is a directory"),
])
def test_eval_fidelity_of_a_run_whose_report_is_unreadable_names_it(tmp_path, capsys, report, said):
    """The run's character comes from its report.json: one that cannot be read is named
    (it was a traceback for a list, and the default avatar's figures without a word else)."""
    run = tmp_path / "out" / "sample"
    run.mkdir(parents=True)
    for name in ("track.npz", "animation.npz"):
        (run / name).write_bytes(b"")
    if report is None:
        (run / "report.json").mkdir()
    else:
        (run / "report.json").write_bytes(report)
    line = _main(capsys, "eval", "fidelity", str(run))
    assert line.startswith(f"capture2face: error: {run / 'report.json'}: cannot be read ({said}"), line
    assert "the character the run used is unknown" in line


# ---- item 13: a folder where a file is meant ---------------------------------------------------
@pytest.mark.parametrize("flag, said", [
    ("--neutral-image", "--neutral-image {d}: is a folder; give an image file"),
    ("--neutral-clip", "--neutral-clip {d}: is a folder; give a video file"),
    ("--face-model", "face model {d} (from --face-model) is a folder; give the model file itself"),
])
@pytest.mark.parametrize("command", ["run", "track"])
def test_a_folder_given_for_a_file_says_so(tmp_path, no_tracking, capsys, flag, said, command):
    folder = tmp_path / "adir"
    folder.mkdir()
    out = ["-o", str(tmp_path / "out")] if command == "run" else ["-o", str(tmp_path / "t.npz")]
    line = _main(capsys, command, str(SAMPLE), *out, flag, str(folder))
    assert said.format(d=folder) in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir"]


def test_a_folder_in_the_face_model_variable_says_so(tmp_path, no_tracking, capsys, monkeypatch):
    monkeypatch.setenv("CAPTURE2FACE_FACE_MODEL", str(tmp_path))
    line = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path / "out"))
    assert f"face model {tmp_path} (from $CAPTURE2FACE_FACE_MODEL) is a folder" in line


# ---- item 13: an image too large to decode says its size -------------------------------------
def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png(path: Path, width: int, height: int) -> Path:
    """A valid black 1-bit PNG of any size: its rows of zeros compress to almost nothing."""
    z = zlib.compressobj(9)
    row = bytes(1 + (width + 7) // 8)
    idat = b"".join(z.compress(row) for _ in range(height)) + z.flush()
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0))
                     + _chunk(b"IDAT", idat) + _chunk(b"IEND", b""))
    return path


@pytest.fixture(scope="module")
def huge_png(tmp_path_factory) -> Path:
    return _png(tmp_path_factory.mktemp("huge") / "huge.png", 36000, 36000)  # 160 KB


SIZE_SAID = "the image is 36000x36000 pixels, too large to decode (FFmpeg's limit is about 268 million pixels"


def test_a_huge_neutral_image_says_its_size_before_tracking(huge_png, tmp_path, no_tracking, capsys):
    line = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path / "out"), "--neutral-image", str(huge_png))
    assert f"--neutral-image: {huge_png}: {SIZE_SAID}" in line and "corrupt" not in line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["run", "track"])
def test_a_huge_image_as_the_clip_says_its_size(huge_png, tmp_path, no_tracking, capsys, command):
    out = str(tmp_path / ("out" if command == "run" else "t.npz"))
    line = _main(capsys, command, str(huge_png), "-o", out)
    assert f"{huge_png}: {SIZE_SAID}" in line and "corrupt" not in line


def test_image_size_from_the_header_and_ffmpegs_limit(tmp_path):
    assert image_size(_png(tmp_path / "a.png", 300, 200)) == (300, 200)
    jpeg = b"\xff\xd8" + b"\xff\xe0" + struct.pack(">H", 16) + bytes(14) \
        + b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, 36000, 40000, 1) + bytes(3)
    (tmp_path / "a.jpg").write_bytes(jpeg)
    assert image_size(tmp_path / "a.jpg") == (40000, 36000)
    assert image_size(SAMPLE) is None
    assert not _too_large(16000, 16000) and not _too_large(100000, 10)  # FFmpeg decodes these
    assert _too_large(16256, 16256) and _too_large(36000, 36000)  # and refuses these


def test_a_damaged_image_is_still_called_damaged(tmp_path, no_tracking, capsys):
    png = _png(tmp_path / "cut.png", 64, 64)
    png.write_bytes(png.read_bytes()[:40])
    line = _main(capsys, "run", str(png), "-o", str(tmp_path / "out"))
    assert "too large" not in line and ("corrupt" in line or "truncated" in line or "not a video" in line)


# ---- item 13: eval synthetic --actor with no face names the actor ------------------------------
def _cube_glb(path: Path) -> Path:
    """A cube with one ARKit-named morph: it loads and drives, but has no face."""
    bld = GlbBuilder()
    v = np.array([[x, y, z] for x in (-.1, .1) for y in (-.1, .1) for z in (-.1, .1)], np.float32)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.uint16).reshape(-1)
    prim = {"attributes": {"POSITION": bld.accessor(v, ARRAY_BUFFER, minmax=True)},
            "indices": bld.accessor(f, 34963),
            "targets": [{"POSITION": bld.accessor(np.full((8, 3), 0.01, np.float32), ARRAY_BUFFER, minmax=True)}]}
    bld.add("meshes", {"primitives": [prim], "extras": {"targetNames": ["jawOpen"]}})
    bld.add("nodes", {"mesh": 0})
    bld.gltf["scenes"] = [{"nodes": [0]}]
    path.write_bytes(bld.to_bytes())
    return path


def test_an_actor_without_a_face_is_named_not_its_temporary_video(tmp_path, capsys):
    cube = _cube_glb(tmp_path / "cube.glb")
    line = _main(capsys, "eval", "synthetic", "--actor", str(cube), "--frames", "12", "--size", "128")
    assert f"actor {cube}: the tracker finds no face in the 12 frames rendered of it" in line
    assert "synthetic.mp4" not in line and "capture2face-eval-" not in line


# ---- item 14: --name that a run's own hidden files use, or not a folder name ----------------------
@pytest.mark.parametrize("name, said", [
    (".capture2face-sample.lock", "starts with '.capture2face-'"),
    (".capture2face-x", "starts with '.capture2face-'"),
    (".tmp-sample", "starts with '.tmp-'"),
    ("", "is empty"),
    ("  ", "is empty"),
    (".", "'.' is not a folder name"),
    ("..", "'..' is not a folder name"),
    ("a/b", "contains a path separator"),
    ("/abs", "contains a path separator"),
    ("x" * 240, "is too long (240 bytes; at most 236)"),
    ("x\ny", "contains a control character"),
    ("take\t2", "contains a control character"),
])
def test_a_name_a_run_cannot_own_is_refused(tmp_path, no_tracking, capsys, name, said):
    line = _main(capsys, "run", str(SAMPLE), "-o", str(tmp_path / "out"), "--name", name)
    assert line.startswith(f"capture2face: error: --name {name!r}: {said}")
    assert not (tmp_path / "out").exists()


def test_a_clip_whose_stem_a_run_cannot_own_asks_for_name(tmp_path, no_tracking, capsys):
    clip = tmp_path / ".capture2face-take.lock.mp4"
    shutil.copy(SAMPLE, clip)
    line = _main(capsys, "run", str(clip), "-o", str(tmp_path / "out"))
    assert "the output folder's name '.capture2face-take.lock' starts with '.capture2face-'" in line
    assert line.endswith("give another with --name")
    assert not (tmp_path / "out").exists()


# ---- item 15: tools/mirror_identity.py -----------------------------------------------------
def _mirror(*args, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, str(MIRROR), *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=env, cwd=cwd, check=False)


def _mirror_fails(done: subprocess.CompletedProcess, said: str) -> None:
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-2000:]
    assert lines[0].startswith("mirror_identity.py: error: ") and said in lines[0], lines[0]


@pytest.fixture
def heads(tmp_path) -> tuple[Path, Path]:
    a = tmp_path / "a.glb"
    shutil.copy(shared_character("ict-a.glb"), a)
    return a, shared_character("ict-b.glb")


def test_mirror_failing_at_the_write_leaves_no_partial_file(tmp_path, heads):
    a, b = heads
    (tmp_path / "out.glb").mkdir()  # in the way: refused before any work
    _mirror_fails(_mirror(a, b, "out.glb", cwd=tmp_path), "out.glb: is a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "out.glb"]
    assert not any((tmp_path / "out.glb").iterdir())


def test_mirror_write_error_leaves_nothing_and_names_the_output(tmp_path, heads, monkeypatch):
    """A failure while writing (here: a replace that fails) removes what was written."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("mirror_identity", MIRROR)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    a, b = heads

    def broken(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", broken)
    with pytest.raises(ValueError, match=r"cannot write .*new\.glb: No space left on device"):
        tool.mirror_identity(a, b, tmp_path / "new.glb")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb"]


@pytest.mark.parametrize("out", ["a.glb", "./a.glb", "link.glb", "hard.glb", "B"])
def test_mirror_never_overwrites_its_input(tmp_path, heads, out):
    a, b = heads
    os.symlink("a.glb", tmp_path / "link.glb")
    os.link(a, tmp_path / "hard.glb")
    before = a.read_bytes()
    out = str(b) if out == "B" else out
    _mirror_fails(_mirror(a, b, out, cwd=tmp_path), "is the input")
    assert a.read_bytes() == before and b.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "hard.glb", "link.glb"]


def test_mirror_writes_the_new_head(tmp_path, heads):
    a, b = heads
    done = _mirror(a, b, "c.glb", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "c.glb").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.glb", "c.glb"]

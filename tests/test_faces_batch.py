"""Issue 15, findings 6 and 7: ``batch --resume`` re-runs a clip made with other options and
the batch report keeps every clip's entry; several faces in view are counted, warned about
and chosen with ``--face N`` / ``--faces largest|center``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from capture2face.batch import _failure_line, resume_check, run_batch
from capture2face.errors import CaptureError
from capture2face.pipeline import OUTPUT_FILES, RunOptions, options_json
from capture2face.render import RenderOptions
from capture2face.tracking import TrackOptions, track_clip
from capture2face.tracking.landmarker import LandmarkerOptions
from tests.helpers import shared_clip


def _cheap(**more) -> RunOptions:
    """A run at 64 px without compare.mp4."""
    return RunOptions(render=RenderOptions(size=64), compare=False, **more)


# ------------------------------------------------------------------ several faces

@pytest.fixture(scope="module")
def two_faces(tmp_path_factory) -> Path:
    """12 frames of ../shared/clips/d3.mp4, twice side by side: a large copy on the left
    (face 0) and a smaller one on the right (face 1)."""
    import cv2

    from capture2face.io.video_input import iter_frames
    from capture2face.io.video_output import VideoWriter

    src = shared_clip("d3.mp4")
    path = tmp_path_factory.mktemp("faces") / "two.mp4"
    with VideoWriter(path, 30, (768, 384)) as out:
        for _, rgb in iter_frames(src, max_frames=12):
            canvas = np.full((384, 768, 3), 90, np.uint8)
            canvas[:, :384] = cv2.resize(rgb, (384, 384), interpolation=cv2.INTER_AREA)
            canvas[64:320, 448:704] = cv2.resize(rgb, (256, 256), interpolation=cv2.INTER_AREA)
            out.write(canvas)
    return path


def _mean_x(track) -> np.ndarray:
    return track.landmarks_px[:, :, 0].mean(1)


def test_largest_and_face_index_pick_different_faces(two_faces):
    largest = track_clip(two_faces, TrackOptions(landmarker=LandmarkerOptions(faces="largest")), progress=False)
    second = track_clip(two_faces, TrackOptions(landmarker=LandmarkerOptions(face=1)), progress=False)
    first = track_clip(two_faces, TrackOptions(landmarker=LandmarkerOptions(face=0)), progress=False)
    for track in (largest, second, first):
        assert track.n_faces_max == 2 and track.presence.all()
    assert (_mean_x(largest) < 384).all()  # the big face, on the left
    assert (_mean_x(second) > 448).all()  # face 1 from the left: the small one
    np.testing.assert_allclose(_mean_x(first), _mean_x(largest), atol=1.0)
    # One face looked for: no choice, no count (today's single-face tracking).
    assert track_clip(two_faces, TrackOptions(landmarker=LandmarkerOptions(num_faces=1)),
                      progress=False).n_faces_max == 1


def test_a_face_index_never_in_view_fails_in_one_line(two_faces):
    with pytest.raises(CaptureError, match=r"--face 2: never more than 2 face"):
        track_clip(two_faces, TrackOptions(landmarker=LandmarkerOptions(face=2)), progress=False)


def test_run_warns_how_many_faces_were_seen(two_faces, tmp_path):
    from capture2face.pipeline import run

    report = run(two_faces, tmp_path, _cheap(track=TrackOptions(landmarker=LandmarkerOptions(face=1))), progress=False)
    warned = [w for w in report["warnings"] if "faces in view" in w]
    assert len(warned) == 1 and warned[0].startswith("2 faces in view") and "face 1 from the left" in warned[0]
    stored = json.loads((tmp_path / "two" / "report.json").read_text())
    assert stored["warnings"] == report["warnings"] and stored["options"]["face"] == 1
    track = np.load(tmp_path / "two" / "track.npz")
    assert int(track["n_faces_max"]) == 2


def test_face_options_are_checked_and_on_the_command_line():
    with pytest.raises(CaptureError, match="--faces"):
        RunOptions(track=TrackOptions(landmarker=LandmarkerOptions(faces="leftmost"))).validate()
    with pytest.raises(CaptureError, match="--face"):
        RunOptions(track=TrackOptions(landmarker=LandmarkerOptions(face=-1))).validate()
    from capture2face.cli import build_parser

    for cmd in (["run", "x.mp4", "-o", "o"], ["batch", "x.mp4", "-o", "o"], ["track", "x.mp4", "-o", "t.npz"]):
        args = build_parser().parse_args(cmd + ["--face", "1", "--faces", "center"])
        assert (args.face, args.faces) == (1, "center")
        assert build_parser().parse_args(cmd).faces == "largest"


# ------------------------------------------------------------------ batch resume, report

@pytest.fixture(scope="module")
def short_clip(tmp_path_factory) -> Path:
    from capture2face.synth import SynthOptions, synthesize

    path = tmp_path_factory.mktemp("short") / "short.mp4"
    synthesize(path, SynthOptions(frames=12, size=256, seed=2, expression=False), progress=False)
    return path


def _entries(out: Path) -> dict:
    return {c["name"]: c for c in json.loads((out / "batch_report.json").read_text())["clips"]}


def test_resume_skips_same_options_and_reruns_changed_ones(short_clip, tmp_path):
    out = tmp_path / "out"
    first = run_batch([short_clip], out, _cheap(), jobs=1, progress=False)
    assert first["clips"][0]["status"] == "ok" and "rerun" not in first["clips"][0]
    stamp = (out / "short" / "avatar.mp4").stat().st_mtime_ns

    same = run_batch([short_clip], out, _cheap(), jobs=1, resume=True, progress=False)
    assert same["clips"][0]["status"] == "skipped" and "rerun" not in same["clips"][0]
    assert (out / "short" / "avatar.mp4").stat().st_mtime_ns == stamp

    bigger = run_batch([short_clip], out, RunOptions(render=RenderOptions(size=128), compare=False), jobs=1,
                       resume=True, progress=False)
    entry = bigger["clips"][0]
    assert entry["status"] == "ok" and entry["rerun"] == "options changed: size 64 -> 128"
    assert json.loads((out / "short" / "report.json").read_text())["size"] == 128
    assert _entries(out)["short"]["rerun"] == "options changed: size 64 -> 128"

    # The batch report keeps the entries of earlier batches for other clips ...
    bad = tmp_path / "bad.mp4"
    bad.write_text("not a video\n")
    other = run_batch([bad], out, _cheap(), jobs=1, progress=False)
    entries = _entries(out)
    assert set(entries) == {"short", "bad"}
    assert entries["short"]["status"] == "ok" and entries["short"]["earlier"] is True
    assert entries["bad"]["status"] == "failed" and "earlier" not in entries["bad"]
    assert other["summary"] == {"ok": 0, "failed": 1, "skipped": 0, "pending": 0} and other["earlier"] == 1
    # ... and this batch's entries replace theirs (one entry a clip).
    again = run_batch([short_clip], out, RunOptions(render=RenderOptions(size=128), compare=False), jobs=1, resume=True,
                      progress=False)
    names = [c["name"] for c in again["clips"]]
    assert sorted(names) == ["bad", "short"]
    entries = _entries(out)
    assert entries["short"]["status"] == "skipped" and "earlier" not in entries["short"]
    assert entries["bad"]["earlier"] is True


def _fake_run(folder: Path, options: RunOptions, drop: tuple[str, ...] = ()) -> None:
    folder.mkdir(parents=True)
    names = [n for n in OUTPUT_FILES if n != "compare.mp4" or options.compare]
    for n in names:
        (folder / n).write_text("x")
    stored = {k: v for k, v in options_json(options).items() if k not in drop}
    (folder / "report.json").write_text(json.dumps({"outputs": names, "options": stored}))


def test_resume_check_normalises_the_stored_options(tmp_path):
    _fake_run(tmp_path / "a", RunOptions(character="default", render=RenderOptions(size=512), queue_frames=2),
              drop=("faces", "face"))
    # An older report without the face options: they count as their defaults; the default
    # avatar by name or as None is the same character; queue_frames changes no output.
    assert resume_check(tmp_path / "a", RunOptions()) == (True, None)
    skip, why = resume_check(tmp_path / "a", RunOptions(render=RenderOptions(size=256),
                                                       track=TrackOptions(landmarker=LandmarkerOptions(faces="center"))))
    assert not skip and why == "options changed: size 512 -> 256, faces largest -> center"
    assert resume_check(tmp_path / "a", RunOptions(character="wide"))[1] == "options changed: character default -> wide"

    rig = tmp_path / "rig.npz"
    rig.write_bytes(b"x")
    _fake_run(tmp_path / "b", RunOptions(character=str(rig)))
    assert resume_check(tmp_path / "b", RunOptions(character=rig))[0]  # a path by any spelling
    (tmp_path / "b" / "livelink.csv").unlink()
    assert resume_check(tmp_path / "b", RunOptions(character=rig)) == (False, "outputs incomplete")
    assert resume_check(tmp_path / "none", RunOptions()) == (False, None)  # never run: no reason


def test_failure_lines_name_the_clip_once():
    path = "/clips/bad.mp4"
    assert _failure_line(path, f"{path}: not a video FFmpeg can read") == f"failed: {path}: not a video FFmpeg can read"
    assert _failure_line(path, "the worker process crashed on this clip") == \
        f"failed: {path}: the worker process crashed on this clip"


def _face(cx: float, cy: float, size: float) -> np.ndarray:
    """A fake landmark set: a square of ``size`` (normalised) around (cx, cy)."""
    g = np.linspace(-0.5, 0.5, 5)
    xy = np.array([(cx + size * a, cy + size * b) for a in g for b in g], np.float32)
    return np.column_stack([xy, np.zeros(len(xy), np.float32)])


@pytest.mark.parametrize("kw, first", [({"faces": "largest"}, 0), ({"faces": "center"}, 1),
                                       ({"face": 0}, 2), ({"face": 2}, 0)])
def test_the_choice_then_continuity(kw, first):
    from capture2face.tracking.landmarker import FaceLandmarker, LandmarkerOptions

    lm = FaceLandmarker(None, LandmarkerOptions(**kw))
    # Big face right, a small one at the centre, another at the left.
    faces = [_face(0.8, 0.5, 0.3), _face(0.5, 0.5, 0.1), _face(0.15, 0.5, 0.12)]
    assert lm._choose(faces, 400, 400) == first
    moved = [f + np.array([0.02, 0.0, 0.0], np.float32) for f in faces]
    assert lm._choose(moved[::-1], 400, 400) == 2 - first  # the same face, listed in another order

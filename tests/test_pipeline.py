"""``capture2face run`` end to end: every output, frame counts, exports that load back,
wrinkle influences that follow the real face, determinism."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capture2face.render import RenderOptions
from tests.helpers import shared_clip

LIVELINK_HEADER = (
    "Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,"
    "EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,EyeLookUpRight,"
    "EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,MouthFunnel,MouthPucker,"
    "MouthRight,MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,MouthFrownRight,MouthDimpleLeft,"
    "MouthDimpleRight,MouthStretchLeft,MouthStretchRight,MouthRollLower,MouthRollUpper,MouthShrugLower,"
    "MouthShrugUpper,MouthPressLeft,MouthPressRight,MouthLowerDownLeft,MouthLowerDownRight,MouthUpperUpLeft,"
    "MouthUpperUpRight,BrowDownLeft,BrowDownRight,BrowInnerUp,BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,"
    "CheekSquintLeft,CheekSquintRight,NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,"
    "LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"
)
OUTPUTS = ["avatar.mp4", "compare.mp4", "track.npz", "animation.npz", "animation.glb", "livelink.csv", "report.html",
           "report.json"]
SIZE = 256


def video_stats(path: Path) -> tuple[int, float, int, int]:
    """(decoded frame count, nominal fps, width, height)."""
    import av

    with av.open(str(path)) as c:
        s = c.streams.video[0]
        n = sum(1 for _ in c.decode(s))
        return n, float(s.average_rate), s.codec_context.width, s.codec_context.height


def check_outputs(folder: Path, clip: Path) -> dict:
    """Every check of issue 6 on one run's output folder; returns its report."""
    from capture2face.gltf import import_glb
    from capture2face.gltf.animation_export import read_animation_keyframe_count, read_glb_animation
    from capture2face.retarget.animation import Animation
    from capture2face.tracking.track import Track

    assert sorted(p.name for p in folder.iterdir()) == sorted(OUTPUTS)
    assert not list(folder.parent.glob(".tmp-*")), "staging left behind"
    n_clip, fps_clip, w_clip, h_clip = video_stats(clip)

    report = json.loads((folder / "report.json").read_text())
    assert report["frames"] == n_clip
    assert 0 < report["tracked_frames"] <= n_clip
    assert report["fps"] == pytest.approx(fps_clip, rel=1e-3)
    assert set(report["seconds"]) >= {"track", "retarget", "export", "render_encode", "total"}
    assert report["seconds"]["total"] >= report["seconds"]["track"] > 0
    assert isinstance(report["warnings"], list)
    assert sorted(report["outputs"]) == sorted(OUTPUTS)

    n, fps, w, h = video_stats(folder / "avatar.mp4")
    assert (n, w, h) == (n_clip, SIZE, SIZE)
    assert fps == pytest.approx(fps_clip, rel=1e-3)
    n, fps, w, h = video_stats(folder / "compare.mp4")
    assert (n, w, h) == (n_clip, 3 * SIZE, SIZE)

    track = Track.load(folder / "track.npz")
    assert track.n_frames == n_clip and (track.width, track.height) == (w_clip, h_clip)
    animation = Animation.load(folder / "animation.npz")
    assert animation.n_frames == n_clip
    np.testing.assert_array_equal(animation.presence, track.presence)

    lines = (folder / "livelink.csv").read_text().splitlines()
    assert lines[0] == LIVELINK_HEADER
    assert len(lines) == 1 + n_clip
    for row in lines[1:]:
        cells = row.split(",")
        assert len(cells) == 63 and cells[1] == "61"
    values = np.array([[float(x) for x in row.split(",")[2:]] for row in lines[1:]])
    assert np.isfinite(values).all() and values[:, :52].min() >= 0 and values[:, :52].max() <= 1
    # The blendshape columns are the animation's ARKit curves (to the CSV's 6 decimals),
    # found by name: JawOpen follows the jaw through the clip, not a constant.
    columns = LIVELINK_HEADER.split(",")[2:]
    curves = {name.lower(): animation.arkit_weights[:, i] for i, name in enumerate(animation.arkit_names)}
    jaw = values[:, columns.index("JawOpen")]
    assert jaw.max() - jaw.min() > 0.2
    for c, name in enumerate(columns[:52]):
        expected = np.clip(curves.get(name.lower(), np.zeros(n_clip)), 0, 1)
        np.testing.assert_allclose(values[:, c], expected, atol=1e-5, err_msg=name)
    # Head yaw is the head pose's, a quarter turn being 1.
    r = animation.head_pose[:, :3, :3].astype(np.float64)
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    yaw = np.arctan2(r[:, 0, 2], r[:, 2, 2]) / (np.pi / 2)
    np.testing.assert_allclose(values[:, columns.index("HeadYaw")], yaw, atol=2e-3)

    rig = import_glb(folder / "animation.glb")
    assert rig.n_vertices > 0 and rig.n_bones == len(animation.bone_names)
    assert read_animation_keyframe_count(folder / "animation.glb") == n_clip
    glb = read_glb_animation(folder / "animation.glb")
    assert len(glb.times) == n_clip
    np.testing.assert_allclose(glb.bone_positions, animation.bone_positions, atol=1e-3)
    return report


@pytest.fixture(scope="module")
def sample_run(sample_clip, tmp_path_factory):
    from capture2face.pipeline import RunOptions, run

    out = tmp_path_factory.mktemp("run")
    report = run(sample_clip, out, RunOptions(render=RenderOptions(size=SIZE)), progress=False)
    return out / sample_clip.stem, report


@pytest.mark.slow
def test_run_writes_every_output_for_the_sample_clip(sample_run, sample_clip):
    folder, report = sample_run
    assert report == check_outputs(folder, sample_clip)
    assert report["tracked_frames"] == report["frames"]  # the synthetic face never leaves
    # The avatar is not a blank frame: the face covers a good part of it and moves.
    import av

    with av.open(str(folder / "avatar.mp4")) as c:
        frames = np.stack([f.to_ndarray(format="gray") for f in c.decode(video=0)]).astype(np.float32)
    background = np.median(frames[:, :4, :4])
    face = np.abs(frames - background) > 20
    assert 0.15 < face.mean() < 0.8
    assert np.abs(np.diff(frames, axis=0)).mean() > 0.2


@pytest.mark.slow
def test_report_html_is_a_self_contained_page_of_the_run(sample_run):
    import re

    folder, report = sample_run
    assert "report.html" in report["outputs"]
    page = (folder / "report.html").read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert not re.search(r"https?://", page), "report.html must not reach the network"
    assert "<script" not in page and "<link" not in page
    # Poster frames of compare.mp4 as embedded JPEGs, plots as inline SVG.
    assert 4 <= page.count('src="data:image/jpeg;base64,') <= 6
    assert page.count("<svg") >= 6 + 3 + 2  # fidelity measures, ARKit groups, stretch/compress
    # The fidelity table shows report.json's figures (same r values, same order).
    fidelity = report["fidelity"]
    assert fidelity["frames"] == report["tracked_frames"]
    shown = re.findall(r'<td class="r">([-0-9.]+)</td>', page)
    assert shown == [f"{m['r']:.3f}" for m in fidelity["measures"].values()]
    assert f"{report['frames']} frames" in page and html_text(report["character"]) in page


def html_text(text: str) -> str:
    import html

    return html.escape(str(text))


@pytest.mark.slow
def test_outputs_are_readable_by_others(sample_run):
    folder, _ = sample_run
    umask = os.umask(0)
    os.umask(umask)
    for p in [folder, *folder.iterdir()]:
        expected = (0o777 if p.is_dir() else 0o666) & ~umask
        assert p.stat().st_mode & 0o777 == expected, p


@pytest.mark.slow
def test_same_input_gives_the_same_animation(sample_run, sample_clip):
    from capture2face.pipeline import RunOptions, load_character, retarget_stage, track_stage
    from capture2face.retarget.animation import Animation

    folder, _ = sample_run
    saved = np.load(folder / "animation.npz")
    again = retarget_stage(track_stage(sample_clip, RunOptions(render=RenderOptions(size=SIZE)), progress=False),
                           load_character(None))
    again_path = folder.parent / "again.animation.npz"
    again.save(again_path)
    fresh = np.load(again_path)
    assert sorted(saved.files) == sorted(fresh.files)
    for key in saved.files:
        np.testing.assert_array_equal(saved[key], fresh[key], err_msg=key)
    assert Animation.load(again_path).n_frames == again.n_frames


@pytest.mark.slow
@pytest.mark.shared_clips
def test_cli_run_on_a_real_clip(tmp_path):
    clip = shared_clip("d0.mp4")
    out = tmp_path / "out"
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    result = subprocess.run([sys.executable, "-m", "capture2face", "-q", "run", str(clip), "-o", str(out),
                             "--size", str(SIZE)], capture_output=True, text=True, timeout=900, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "wrote" in result.stdout
    report = check_outputs(out / "d0", clip)
    assert report["tracked_frames"] == 78


def _brow_series(clip_name: str):
    """(forehead stretch influence, glabella compress influence, browInnerUp, browDown)."""
    from capture2face.pipeline import RunOptions, load_character, retarget_stage, track_stage

    track = track_stage(shared_clip(clip_name), RunOptions(), progress=False)
    anim = retarget_stage(track, load_character(None))
    names = track.blendshape_names
    up = track.blendshapes[:, names.index("browInnerUp")]
    down = track.blendshapes[:, [names.index("browDownLeft"), names.index("browDownRight")]].mean(1)
    ri = anim.region_influence
    stretch = ri[:, anim.region_names.index("forehead"), anim.pose_names.index("stretch")]
    compress = ri[:, anim.region_names.index("glabella"), anim.pose_names.index("compress")]
    return stretch, compress, up, down


@pytest.mark.slow
@pytest.mark.shared_clips
def test_forehead_stretch_follows_raised_brows():
    """d12 (talking, surprise): MediaPipe's browInnerUp swings 0..1 over the clip."""
    stretch, _, up, _ = _brow_series("d12.mp4")
    assert np.ptp(up) > 0.5 and np.ptp(stretch) > 0
    assert np.corrcoef(stretch, up)[0, 1] > 0.5


@pytest.mark.slow
@pytest.mark.shared_clips
def test_glabella_compress_follows_frowns():
    """d3 (frowns): MediaPipe's browDown (mean of left and right) rises to ~0.7."""
    _, compress, _, down = _brow_series("d3.mp4")
    assert np.ptp(down) > 0.4 and np.ptp(compress) > 0
    assert np.corrcoef(compress, down)[0, 1] > 0.5


def test_compare_frame_puts_landmarks_on_the_source_pixels():
    from capture2face.pipeline.compose import SourceFitter, compare_frame

    source = np.zeros((480, 640, 3), np.uint8)
    source[300:310, 100:110] = 255  # a white square centred on (105, 305)
    fitter = SourceFitter(640, 480, 256)  # letterboxed: scale 0.4, bars above and below
    avatar = np.full((256, 256, 3), 7, np.uint8)
    out = compare_frame(fitter, source, np.array([[105.0, 305.0]]), True, avatar, np.zeros((128, 128, 3), np.uint8))
    assert out.shape == (256, 768, 3)
    np.testing.assert_array_equal(out[40:, 256:512], avatar[40:])  # middle panel untouched below its label
    assert out[:32, 200:256].max() == 0 and out[-32:, :256].max() == 0  # black bars
    bright = np.argwhere(fitter.fit(source)[..., 0] > 128).mean(0)  # (row, col) of the square
    green = np.argwhere((out[:, :256, 1] > 200) & (out[:, :256, 0] < 100))
    assert len(green) >= 1
    np.testing.assert_allclose(green.mean(0), bright, atol=1.0)
    np.testing.assert_allclose(fitter.to_panel([[105.0, 305.0]])[0], [105 * 0.4, 305 * 0.4 + 32])


def test_characters_load_from_npz_glb_and_builtin_names(tmp_path):
    from capture2face.gltf import export_glb
    from capture2face.pipeline import load_character
    from capture2face.rig.avatar import default_avatar

    wide = default_avatar(variant="wide")
    wide.save(tmp_path / "wide.npz")
    export_glb(wide, tmp_path / "wide.glb")
    for rig in (load_character(tmp_path / "wide.npz"), load_character(str(tmp_path / "wide.glb")),
                load_character("wide")):
        assert rig.n_vertices == wide.n_vertices and rig.bone_names == wide.bone_names
        np.testing.assert_allclose(rig.bone_rest, wide.bone_rest, atol=1e-5)
    assert load_character(None).n_vertices == default_avatar().n_vertices
    assert load_character(wide) is wide


@pytest.mark.slow
def test_run_with_a_glb_character(sample_clip, tmp_path):
    from capture2face.gltf import export_glb
    from capture2face.pipeline import RunOptions, run
    from capture2face.retarget.animation import Animation
    from capture2face.rig.avatar import default_avatar

    wide = default_avatar(variant="wide")
    export_glb(wide, tmp_path / "hero.glb")
    report = run(sample_clip, tmp_path / "out",
                 RunOptions(character=tmp_path / "hero.glb", render=RenderOptions(size=128), compare=False),
                 progress=False, name="hero_take")
    folder = tmp_path / "out" / "hero_take"
    assert report["character"] == wide.name and report["output_dir"] == str(folder)
    assert "compare.mp4" not in report["outputs"] and not (folder / "compare.mp4").exists()
    anim = Animation.load(folder / "animation.npz")
    assert anim.character == wide.name and anim.n_frames == report["frames"]
    n, _, w, h = video_stats(folder / "avatar.mp4")
    assert (n, w, h) == (report["frames"], 128, 128)
    assert "report.html" in report["outputs"]  # its posters are avatar.mp4's frames then
    assert "data:image/jpeg" in (folder / "report.html").read_text(encoding="utf-8")


@pytest.mark.slow
def test_a_face_that_leaves_the_frame_keeps_every_frame(tmp_path):
    """Frames without a face still get an avatar frame, a Live Link row and a keyframe;
    the report says how many frames had no face."""
    from capture2face.pipeline import RunOptions, run
    from capture2face.synth import SynthOptions, synthesize

    clip = tmp_path / "exit.mp4"
    synthesize(clip, SynthOptions(frames=75, size=256, seed=4, face_exit=True), progress=False)
    report = run(clip, tmp_path / "out", RunOptions(render=RenderOptions(size=128), compare=False), progress=False)
    folder = tmp_path / "out" / "exit"
    assert report["frames"] == 75 and report["tracked_frames"] < 75
    assert any("no face in" in w for w in report["warnings"])
    assert video_stats(folder / "avatar.mp4")[0] == 75
    assert len((folder / "livelink.csv").read_text().splitlines()) == 76
    from capture2face.gltf.animation_export import read_animation_keyframe_count

    assert read_animation_keyframe_count(folder / "animation.glb") == 75


def test_avatar_follows_the_tracked_head_rotation_centred():
    from capture2face.camera import framing_pose, rotation_matrix
    from capture2face.pipeline import avatar_head_poses, load_character

    rig = load_character(None)
    tracked = np.tile(np.eye(4), (3, 1, 1))
    tracked[:, :3, 3] = [[0, 0, -40], [5, -3, -60], [-2, 1, -35]]  # the source camera's distance is ignored
    tracked[1, :3, :3] = rotation_matrix(20, 5, -3)
    tracked[2, :3, :3] = rotation_matrix(-15, -8, 6)
    poses = avatar_head_poses(rig, tracked, 30.0)
    for pose, angles in zip(poses, [(0, 0, 0), (20, 5, -3), (-15, -8, 6)]):
        np.testing.assert_allclose(pose, framing_pose(rig, *angles, fov_y_degrees=30.0), atol=1e-9)


def test_encoders_get_threads_only_where_cores_are_free():
    from capture2face.pipeline import encoder_threads

    assert encoder_threads(software_gl=True, cores=16) == 1  # llvmpipe takes every core
    assert encoder_threads(software_gl=False, cores=2) == 1
    assert encoder_threads(software_gl=False, cores=16) == 7  # two encoders, GL + decode beside
    assert encoder_threads(software_gl=False, cores=64) == 8


@pytest.mark.slow
def test_exports_written_beside_the_render_where_cores_are_free(sample_run, sample_clip, tmp_path, monkeypatch):
    from capture2face.pipeline import RunOptions, run, runner

    monkeypatch.setattr(runner, "free_cores", lambda: 8)  # the exports go in a thread beside the render
    report = run(sample_clip, tmp_path, RunOptions(render=RenderOptions(size=SIZE)), progress=False)
    folder, _ = sample_run
    for name in ("animation.npz", "livelink.csv"):  # the same files as written after the render
        assert (tmp_path / sample_clip.stem / name).read_bytes() == (folder / name).read_bytes(), name
    assert report["seconds"]["export"] > 0 and report["seconds"]["checks"] > 0


def test_retarget_options_reach_the_retarget_stage(sample_clip, tmp_path, monkeypatch):
    """``run`` and ``batch`` hand RunOptions.retarget to the retarget stage (no tracking here:
    the track is a stand-in, and the stage stops the run once it has seen its options)."""
    from capture2face import batch
    from capture2face.pipeline import RunOptions, run, runner
    from capture2face.retarget import RetargetOptions
    from capture2face.tracking import TrackOptions

    class Seen(Exception):
        pass

    class StandIn:
        def save(self, path):
            pass

    seen = []

    def fake_retarget_stage(track, rig, options=None):
        seen.append(options)
        raise Seen

    monkeypatch.setattr(runner, "_track", lambda *args: StandIn())
    monkeypatch.setattr(runner, "retarget_stage", fake_retarget_stage)
    options = RunOptions(retarget=RetargetOptions(depth_motion=1.0, n_centers=32), track=TrackOptions(workers=1),
                         render=RenderOptions(size=64), compare=False)
    with pytest.raises(Seen):
        run(sample_clip, tmp_path / "run", options, progress=False)
    report = batch.run_batch([sample_clip], tmp_path / "batch", options, jobs=1, progress=False)
    assert "Seen" in report["clips"][0]["error"]
    assert seen == [options.retarget, options.retarget]

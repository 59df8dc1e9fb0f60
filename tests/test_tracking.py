"""Tracking: head-pose removal, filtering, gaps, neutral frame, Track I/O, real and synthetic clips."""

from __future__ import annotations

import dataclasses
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture2face.errors import CaptureError
from capture2face.eval.filter_tuning import jitter_lag
from capture2face.io.video_input import iter_frames, open_video
from capture2face.topology import BLENDSHAPE_NAMES, IOD_PAIR
from capture2face.tracking import Track, Tracker, TrackOptions, track_clip
from capture2face.tracking.filtering import OneEuro, filter_pose, one_euro
from capture2face.tracking.gaps import fill_gaps, gap_runs
from capture2face.tracking.head_pose import (
    canonical_mesh,
    head_landmarks,
    metric_landmarks,
    project_camera_points,
    to_head,
)
from capture2face.tracking.landmarker import FaceLandmarker, LandmarkerOptions
from capture2face.tracking.neutral import expression_energy, pick_neutral

CLIPS = Path(__file__).parents[2] / "shared" / "clips"
EYES = IOD_PAIR  # outer eye corners: the inter-ocular distance (IOD) used throughout

needs_clips = pytest.mark.skipif(not (CLIPS / "d0.mp4").exists(), reason="../shared/clips absent")


def write_clip(path, frames, fps=25, rotation=None):
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        s.height, s.width = frames[0].shape[:2]
        s.pix_fmt = "yuv420p"
        s.options = {"crf": "16"}
        if rotation is not None:
            s.set_display_rotation(rotation)
        for img in frames:
            for p in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return Path(path)


class Frames(list):
    """Decoded frames with their frame rate."""

    fps: float = 25.0


N_FACE = 48


@pytest.fixture(scope="session")
def face_frames(request):
    """48 frames of a real face (../shared/clips/d0.mp4, 25 fps), or of conftest's synthetic
    performance (30 fps) where the real clips are absent."""
    if (CLIPS / "d0.mp4").exists():
        clip, fps = CLIPS / "d0.mp4", 25.0
    else:
        clip = request.getfixturevalue("synthetic_clip").video_path
        fps = open_video(clip).fps
    frames = Frames(rgb for _, rgb in iter_frames(clip, max_frames=N_FACE))
    frames.fps = fps
    return frames


@pytest.fixture(scope="session")
def face_track(face_frames, tmp_path_factory):
    clip = write_clip(tmp_path_factory.mktemp("face") / "face.mp4", face_frames, fps=face_frames.fps)
    return clip, track_clip(clip, TrackOptions(), progress=False)


# ---------------------------------------------------------------- head pose (no video)

def ideal_screen_landmarks(points_cam, width, height, fov_y=63.0):
    """What a perfect MediaPipe would report for camera-space points (F, N, 3): x, y of
    the projection, z the depth relative to the mean, in MediaPipe's units."""
    px = project_camera_points(points_cam, width, height, fov_y)
    depth = -points_cam[..., 2]
    mean = depth.mean(1, keepdims=True)
    width_near = width / height * 2.0 * np.tan(np.radians(fov_y) / 2.0)
    z = (depth - mean) / (mean * width_near)
    return np.concatenate([px / [width, height], z[..., None]], -1)


def random_poses(n, seed=0):
    rng = np.random.default_rng(seed)
    rot = Rotation.from_euler("yxz", rng.uniform(-35, 35, (n, 3)), degrees=True).as_matrix()
    trans = np.stack([rng.uniform(-8, 8, n), rng.uniform(-6, 6, n), rng.uniform(-90, -30, n)], 1)
    return rot, trans


def test_head_motion_alone_moves_no_landmark_on_ideal_input():
    mesh = canonical_mesh()
    verts = mesh.vertices.astype(np.float64)
    rot, trans = random_poses(40)
    cam = np.einsum("fij,nj->fni", rot, verts) + trans[:, None]
    norm = ideal_screen_landmarks(cam, 640, 480)
    head, pose = head_landmarks(norm, 640, 480, mesh)
    iod = np.linalg.norm(verts[EYES[0]] - verts[EYES[1]])
    assert np.abs(head - verts).max() < 1e-6 * iod
    np.testing.assert_allclose(pose[:, :3, 3], trans, atol=1e-6)
    np.testing.assert_allclose(pose[:, :3, :3], rot, atol=1e-8)


def test_metric_landmarks_reproject_to_the_image():
    rng = np.random.default_rng(3)
    norm = np.concatenate([rng.uniform(0.3, 0.7, (5, 478, 2)), rng.normal(0, 0.02, (5, 478, 1))], -1)
    metric, pose = metric_landmarks(norm, 400, 300)
    px = project_camera_points(metric, 400, 300)
    np.testing.assert_allclose(px, norm[..., :2] * [400, 300], atol=1e-6)
    back = np.einsum("fij,flj->fli", pose[:, :3, :3], to_head(metric, pose)) + pose[:, None, :3, 3]
    np.testing.assert_allclose(back, metric, atol=1e-9)


def test_pose_reproduces_mediapipe_matrix(face_frames):
    norms, mats = [], []
    with FaceLandmarker.create_from_options(LandmarkerOptions()) as lm:
        for i, rgb in enumerate(face_frames[:15]):
            obs = lm.detect(rgb, i / face_frames.fps)
            norms.append(obs.landmarks_norm)
            mats.append(obs.matrix)
            assert obs.landmarks_norm.shape == (478, 3) and obs.blendshapes.shape == (52,)
    h, w = face_frames[0].shape[:2]
    _, pose = head_landmarks(np.array(norms), w, h)
    mats = np.array(mats)
    assert np.abs(pose - mats).max() < 1e-3 * np.abs(mats).max()


# ---------------------------------------------------------------- filtering

def test_one_euro_removes_jitter_keeps_still_signal():
    t = np.arange(300) / 30.0
    rng = np.random.default_rng(0)
    still = np.ones((300, 5, 3))
    np.testing.assert_allclose(one_euro(still, t, OneEuro(1.0, 0.5)), still)
    noisy = still + rng.normal(0, 0.1, still.shape)
    out = one_euro(noisy, t, OneEuro(1.0, 0.0), speed_axis=-1)
    assert out[30:].std() < 0.35 * noisy[30:].std()


def test_one_euro_beta_cuts_lag_and_zero_phase_removes_it():
    t = np.arange(200) / 30.0
    ramp = (10.0 * t)[:, None]  # 10 units/s
    slow = one_euro(ramp, t, OneEuro(1.0, 0.0))
    fast = one_euro(ramp, t, OneEuro(1.0, 1.0))
    lag_slow = (ramp - slow)[100:, 0].mean() / 10.0  # seconds behind
    lag_fast = (ramp - fast)[100:, 0].mean() / 10.0
    assert lag_slow == pytest.approx(1.0 / (2 * np.pi), rel=0.1)  # tau of a 1 Hz low-pass
    assert lag_fast < 0.2 * lag_slow
    zp = one_euro(ramp, t, OneEuro(1.0, 0.0, zero_phase=True))
    assert np.abs(zp - ramp)[40:-40].max() < 1e-3


def test_filter_pose_keeps_rotations_valid_across_the_quaternion_sign_flip():
    t = np.arange(60) / 30.0
    ang = np.linspace(170, 190, 60)  # crosses 180 deg, where q and -q swap
    pose = np.tile(np.eye(4), (60, 1, 1))
    truth = Rotation.from_euler("y", ang[:, None], degrees=True)
    pose[:, :3, :3] = truth.as_matrix()
    pose[:, :3, 3] = [1.0, 2.0, -40.0]
    out = filter_pose(pose, t, OneEuro(1.0, 0.5, zero_phase=True))
    rot = out[:, :3, :3]
    np.testing.assert_allclose(np.einsum("fij,fkj->fik", rot, rot), np.tile(np.eye(3), (60, 1, 1)), atol=1e-9)
    off = np.degrees((Rotation.from_matrix(rot) * truth.inv()).magnitude())
    assert off[10:-10].max() < 0.5
    np.testing.assert_allclose(out[:, :3, 3], pose[:, :3, 3])


def test_jitter_lag_measures_a_known_delay_and_noise():
    t = np.arange(150) / 30.0
    rng = np.random.default_rng(1)
    amp = rng.uniform(0.5, 1.5, 478)
    truth = np.zeros((150, 478, 3))
    truth[:, EYES[0], 0], truth[:, EYES[1], 0] = -4.0, 4.0  # IOD = 8
    truth[:, :, 1] = np.sin(2 * np.pi * 0.7 * t)[:, None] * amp
    estimate = truth.copy()
    estimate[:, :, 1] = np.sin(2 * np.pi * 0.7 * (t - 0.1))[:, None] * amp  # 100 ms late
    estimate += rng.normal(0, 0.08, truth.shape)
    figs = jitter_lag(estimate, truth, t)
    assert figs["lag_ms"] == pytest.approx(100, abs=8)
    assert figs["jitter"] == pytest.approx(100 * 0.08 * np.sqrt(3) / 8, rel=0.15)


# ---------------------------------------------------------------- gaps, neutral

def test_gaps_interpolated_held_and_counted():
    n = 40
    times = np.arange(n) / 20.0  # 20 fps: 0.25 s = 5 frames
    presence = np.ones(n, bool)
    presence[[0, 1]] = False  # leading: held from frame 2
    presence[10:13] = False  # 3 frames: interpolated
    presence[20:30] = False  # 10 frames: long, held
    presence[38:] = False  # trailing: held
    assert gap_runs(presence) == [(0, 2), (10, 13), (20, 30), (38, 40)]
    x = np.where(presence, np.arange(n, dtype=float), np.nan)[:, None].repeat(2, 1)
    pose = np.tile(np.eye(4), (n, 1, 1))
    pose[:, :3, :3] = Rotation.from_euler("z", np.arange(n)[:, None] * 2.0, degrees=True).as_matrix()
    pose[:, :3, 3] = np.arange(n)[:, None]
    pose[~presence] = np.nan
    arrays = {"x": x}
    fill = fill_gaps(times, presence, arrays, pose, 0.25)
    np.testing.assert_allclose(x[10:13, 0], [10, 11, 12])  # linear
    np.testing.assert_allclose(x[20:30, 0], 19)  # holds the last pose
    np.testing.assert_allclose(x[:2, 0], 2)  # leading: the first detection
    np.testing.assert_allclose(x[38:, 0], 37)
    ang = Rotation.from_matrix(pose[10:13, :3, :3]).as_euler("xyz", degrees=True)[:, 2]
    np.testing.assert_allclose(ang, [20, 22, 24], atol=1e-9)  # slerp
    assert fill.interpolated.sum() == 3 and fill.interpolated[10:13].all()
    assert fill.held.sum() == 2 + 10 + 2
    assert (fill.n_gaps, fill.n_long_gaps) == (4, 1)


def test_neutral_is_the_calmest_steady_frame():
    n = 30
    times = np.arange(n) / 30.0
    scores = np.full((n, 52), 0.3)
    scores[:, 0] = 0.0
    scores[7] = 0.05  # calm, but the head is moving fast there
    scores[18] = 0.08  # calm and still
    scores[18, 0] = 1.0  # _neutral is ignored
    scores[18, 11:19] = 0.9  # gaze (eyeLook*) is ignored
    pose = np.tile(np.eye(4), (n, 1, 1))
    pose[:, 0, 3] = np.cumsum(np.where(np.abs(np.arange(n) - 7) <= 2, 3.0, 0.01))
    assert expression_energy(scores, BLENDSHAPE_NAMES)[18] == pytest.approx(43 * 0.08 ** 2)
    assert pick_neutral(scores, BLENDSHAPE_NAMES, pose, times, np.ones(n, bool)) == 18


# ---------------------------------------------------------------- Track

def random_track(n=12, seed=0):
    rng = np.random.default_rng(seed)
    return Track(
        times=np.sort(rng.random(n)), landmarks_px=rng.random((n, 478, 2), np.float32),
        landmarks_depth=rng.random((n, 478), np.float32),
        landmarks_head=rng.random((n, 478, 3), np.float32), presence=rng.random(n) > 0.3,
        interpolated=rng.random(n) > 0.8, held=rng.random(n) > 0.8,
        blendshapes=rng.random((n, 52), np.float32), blendshape_names=list(BLENDSHAPE_NAMES),
        head_pose=rng.random((n, 4, 4), np.float32), neutral_frame=3, width=640, height=480,
        fps=29.97, source="clip.mp4", n_faces_max=2, n_gaps=3, n_long_gaps=1,
    )


def assert_tracks_equal(a: Track, b: Track):
    for f in dataclasses.fields(Track):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), f.name
        else:
            assert x == y and type(x) is type(y), f.name


def test_track_save_load_bit_exact(tmp_path):
    track = random_track()
    track.save(tmp_path / "t.npz")
    assert_tracks_equal(track, Track.load(tmp_path / "t.npz"))


# ---------------------------------------------------------------- real video

def test_tracked_clip_fields(face_frames, face_track, tmp_path):
    clip, track = face_track
    n = N_FACE
    assert track.n_frames == n and track.tracked_frames == n
    assert track.landmarks_px.shape == (n, 478, 2) and track.landmarks_head.shape == (n, 478, 3)
    assert track.blendshapes.shape == (n, 52) and track.blendshape_names[25] == "jawOpen"
    h, w = face_frames[0].shape[:2]
    assert (track.width, track.height, track.fps) == (w, h, face_frames.fps)
    np.testing.assert_allclose(track.times, np.arange(n) / face_frames.fps, atol=1e-9)
    # head coordinates: the face is canonical-sized, eyes level, ~9 cm apart
    iod = np.linalg.norm(track.landmarks_head[:, EYES[0]] - track.landmarks_head[:, EYES[1]], axis=-1)
    assert np.all((iod > 7.5) & (iod < 10.5))
    assert 0 <= track.neutral_frame < n
    track.save(tmp_path / "track.npz")
    assert_tracks_equal(track, Track.load(tmp_path / "track.npz"))


def test_no_face_anywhere(tmp_path):
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (128, 128, 3), dtype=np.uint8) for _ in range(12)]
    clip = write_clip(tmp_path / "noise.mp4", frames)
    with pytest.raises(CaptureError, match="no face found in 12 frames"):
        track_clip(clip, progress=False)


@pytest.mark.parametrize("kind", ["text", "empty", "truncated"])
def test_bad_inputs(tmp_path, kind):
    p = tmp_path / "bad.mp4"
    if kind == "text":
        p.write_text("not a video\n")
        match = "not a video"
    elif kind == "empty":
        p.write_bytes(b"")
        match = "empty"
    else:
        full = write_clip(tmp_path / "ok.mp4", [np.zeros((64, 64, 3), np.uint8)] * 10).read_bytes()
        p.write_bytes(full[: len(full) // 2])
        match = "truncated"
    with pytest.raises(CaptureError, match=match):
        track_clip(p, progress=False)


def test_neutral_frame_option(face_track):
    clip, _ = face_track
    track = track_clip(clip, TrackOptions(neutral_frame=5, max_frames=10), progress=False)
    assert track.neutral_frame == 5 and track.n_frames == 10
    with pytest.raises(CaptureError, match="outside the clip"):
        track_clip(clip, TrackOptions(neutral_frame=99, max_frames=10), progress=False)


def test_rotation_metadata_respected(face_frames, face_track, tmp_path):
    _, upright = face_track
    coded = [np.ascontiguousarray(np.rot90(f, -1)) for f in face_frames[:12]]  # stored sideways
    clip = write_clip(tmp_path / "phone.mp4", coded, fps=face_frames.fps, rotation=90)
    assert open_video(clip).rotation == 90
    track = track_clip(clip, progress=False)
    err = np.linalg.norm(track.landmarks_px - upright.landmarks_px[:12], axis=-1)
    assert np.median(err) < 1.5  # pixels, same orientation as the upright clip


def test_face_leaving_the_frame_is_flagged_and_the_track_resumes(face_frames, tmp_path):
    frames = [f.copy() for f in face_frames]
    a, b = 10, 10 + int(round(face_frames.fps))  # 1 s without the face
    for f in frames[a:b]:
        f[:] = 0
    clip = write_clip(tmp_path / "exit.mp4", frames, fps=face_frames.fps)
    track = track_clip(clip, progress=False)
    assert track.n_long_gaps == 1 and track.n_gaps == 1
    assert not track.presence[a:b].any()
    assert track.held[a:b].all() and not track.interpolated.any()
    assert track.presence[:a].all() and track.presence[b + 1:].all()  # resumes
    np.testing.assert_array_equal(track.landmarks_px[20], track.landmarks_px[9])  # holds


def test_several_faces_keeps_the_one_that_continues_the_track(face_frames, tmp_path):
    import cv2

    small = [cv2.resize(f, (256, 256), interpolation=cv2.INTER_AREA) for f in face_frames[:16]]
    frames = []
    for i, face in enumerate(small):
        canvas = np.full((256, 512, 3), 90, np.uint8)
        canvas[:, 256:] = face  # the tracked face, on the right
        if i >= 6:  # a bigger second face appears on the left
            canvas[:, :256] = cv2.resize(face[24:232, 24:232], (256, 256))
        frames.append(canvas)
    clip = write_clip(tmp_path / "two.mp4", frames, fps=face_frames.fps)
    track = track_clip(clip, TrackOptions(landmarker=LandmarkerOptions(num_faces=2)), progress=False)
    assert track.n_faces_max == 2
    assert track.presence.all()
    assert (track.landmarks_px[:, :, 0].mean(1) > 256).all()


def test_tracker_streaming_matches_track_clip(face_frames, face_track):
    clip, track = face_track
    info = open_video(clip)
    with Tracker(info, TrackOptions()) as tracker:
        for t, rgb in iter_frames(clip):
            tracker.process(t, rgb)
        streamed = tracker.finish()
    np.testing.assert_allclose(streamed.landmarks_head, track.landmarks_head, atol=1e-5)


def test_cli_track_with_overlay(face_track, tmp_path):
    from capture2face.cli import main

    clip, _ = face_track
    out, overlay = tmp_path / "track.npz", tmp_path / "overlay.mp4"
    assert main(["-q", "track", str(clip), "-o", str(out), "--overlay", str(overlay)]) == 0
    track = Track.load(out)
    info = open_video(overlay)
    assert (info.width, info.height, info.n_frames) == (track.width, track.height, track.n_frames)
    # the overlay differs from the source where landmarks are drawn
    _, src = next(iter(iter_frames(clip)))
    _, drawn = next(iter(iter_frames(overlay)))
    x, y = np.round(track.landmarks_px[0, 1]).astype(int)
    assert np.abs(drawn[y - 1:y + 2, x - 1:x + 2].astype(int) - src[y - 1:y + 2, x - 1:x + 2]).mean() > 20
    assert main(["-q", "track", str(tmp_path / "nope.mp4"), "-o", str(out)]) == 2


@pytest.mark.slow
@needs_clips
@pytest.mark.parametrize("name", sorted(p.name for p in CLIPS.glob("*.mp4")) if CLIPS.exists() else [])
def test_every_shared_clip_tracked(name):
    track = track_clip(CLIPS / name, progress=False)
    assert track.tracked_frames >= 0.99 * track.n_frames
    assert track.n_frames >= 0.98 * open_video(CLIPS / name).n_frames


# ---------------------------------------------------------------- synthetic ground truth

@pytest.fixture(scope="session")
def synth_expression(synthetic_clip):
    """conftest's shared synthetic performance (expressions and head motion), tracked."""
    return synthetic_clip, track_clip(synthetic_clip.video_path, progress=False)


@pytest.fixture(scope="session")
def synth_head_only(tmp_path_factory):
    """A synthetic clip with head motion only (one fixed mild expression), tracked."""
    from capture2face.synth import SynthOptions, synthesize

    path = tmp_path_factory.mktemp("synth_head") / "head.mp4"
    clip = synthesize(path, SynthOptions(frames=60, seed=2, expression=False), progress=False)
    return clip, track_clip(clip.video_path, progress=False)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["synth_expression", "synth_head_only"])
def test_landmarks_match_ground_truth(which, request):
    clip, track = request.getfixturevalue(which)
    truth = clip.truth
    assert track.presence.mean() >= 0.99
    iod = np.linalg.norm(truth.landmarks_px[:, EYES[0]] - truth.landmarks_px[:, EYES[1]], axis=-1)
    err = np.linalg.norm(track.landmarks_px - truth.landmarks_px, axis=-1) / iod[:, None]
    assert np.nanmedian(err) <= 0.03


@pytest.mark.slow
def test_head_motion_alone_barely_moves_head_coordinates(synth_head_only):
    clip, track = synth_head_only
    truth = clip.truth
    assert np.ptp(truth.landmarks_head[:, :468], axis=0).max() < 1e-4  # fixed expression
    assert np.ptp(truth.head_angles, axis=0).max() > 8.0  # while the head does move
    head = track.landmarks_head[:, :468].astype(np.float64)
    iod = np.linalg.norm(truth.landmarks_head[0, EYES[0]] - truth.landmarks_head[0, EYES[1]])
    moved = np.linalg.norm(head - np.median(head, axis=0), axis=-1) / iod
    assert np.median(moved) <= 0.01


def test_still_images_are_landmarked_each_on_its_own():
    """IMAGE mode (a character's front views): an image's landmarks do not depend on the
    image before it, and follow the face when it moves; VIDEO mode pulled a mouth-open
    view's lips towards the closed mouth tracked just before."""
    from capture2face.camera import framing_pose
    from capture2face.render import FrameState, Renderer, RenderOptions
    from capture2face.rig.avatar import default_avatar

    rig = default_avatar()
    opts = RenderOptions(size=384, wrinkles="off")
    pose = framing_pose(rig, fov_y_degrees=opts.fov_y_degrees)
    opened = np.zeros(rig.n_morphs, np.float32)
    opened[rig.morph_index("jawOpen")] = 1.0
    with Renderer(rig, opts) as renderer:
        rest = renderer.render(FrameState(rig.bone_rest.copy(), np.zeros(rig.n_morphs, np.float32), pose))
        mouth = renderer.render(FrameState(rig.bone_rest.copy(), opened, pose))
    shifted = np.roll(mouth, 6, axis=1)  # the face 6 px to the right
    with FaceLandmarker.create_from_options(LandmarkerOptions(num_faces=1, still_images=True)) as lm:
        alone = lm.detect(mouth, 0.0).landmarks_px
    with FaceLandmarker.create_from_options(LandmarkerOptions(num_faces=1, still_images=True)) as lm:
        lm.detect(rest, 0.0)
        after_rest = lm.detect(mouth, 0.0).landmarks_px
        moved = lm.detect(shifted, 0.0).landmarks_px
    np.testing.assert_allclose(after_rest, alone, atol=1e-3)
    assert abs(np.median(moved[:, 0] - alone[:, 0]) - 6.0) < 0.5
    assert np.linalg.norm(alone[14] - alone[13]) > 10.0  # the open mouth seen open

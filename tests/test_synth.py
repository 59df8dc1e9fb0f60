"""Synthetic performances: trajectories, ground truth, rendering, trackability."""

from __future__ import annotations

import numpy as np
import pytest

from capture2face.errors import CaptureError
from capture2face.rig.influences import group_influences, pose_influences
from capture2face.synth import SynthOptions, render_performance
from capture2face.synth.trajectories import (
    KEY_NEUTRAL,
    KEY_POSE0,
    PITCH_LIMIT,
    ROLL_LIMIT,
    YAW_LIMIT,
    random_performance,
)
from capture2face.synth.truth import SyntheticTruth, compute_truth, truth_path
from capture2face.topology import IOD_PAIR


def _moving(rig, p):
    """(B,) bones that move in reference pose p."""
    return np.linalg.norm(rig.pose_bones[p] - rig.bone_rest, axis=1) > 1e-4


@pytest.mark.parametrize("frames,seed", [(60, 0), (150, 7)])
def test_trajectory_passes_through_neutral_and_reference_poses(avatar, frames, seed):
    perf = random_performance(avatar, frames, seed=seed)
    raw = pose_influences(perf.bone_positions, avatar.bone_rest, avatar.pose_bones)
    neutral = np.flatnonzero(perf.key_pose == KEY_NEUTRAL)
    assert len(neutral) >= 3 and neutral[0] < 0.1 * frames  # near the start, held
    np.testing.assert_array_equal(perf.bone_positions[neutral],
                                  np.broadcast_to(avatar.bone_rest, (len(neutral),) + avatar.bone_rest.shape))
    assert np.all(perf.blend_weights[neutral] == 0)
    assert np.all(raw[neutral] == 0)
    for p, name in enumerate(avatar.pose_names):
        held = np.flatnonzero(perf.key_pose == KEY_POSE0 + p)
        assert len(held) >= 3, name
        np.testing.assert_allclose(perf.bone_positions[held],
                                   np.broadcast_to(avatar.pose_bones[p], (len(held),) + avatar.pose_bones[p].shape),
                                   atol=1e-6)
        np.testing.assert_allclose(perf.blend_weights[held],
                                   np.broadcast_to(avatar.pose_morph_weights[p], (len(held), avatar.n_morphs)),
                                   atol=1e-6)
        moving = _moving(avatar, p)
        assert moving.sum() >= 2
        np.testing.assert_allclose(raw[held][:, p, moving], 1.0, atol=1e-5)
    # Elsewhere the performance moves: not stuck at one of the held poses.
    free = perf.key_pose < 0
    assert (np.ptp(perf.bone_positions[free], axis=0).max()
            > 0.2 * np.linalg.norm(avatar.pose_bones - avatar.bone_rest, axis=-1).max())
    assert perf.blend_weights.min() >= 0.0 and perf.blend_weights.max() <= 1.0


def test_truth_influences_are_the_grouped_pose_influences(avatar):
    perf = random_performance(avatar, 60, seed=3)
    truth = compute_truth(avatar, perf, 256, 256)
    raw = pose_influences(perf.bone_positions, avatar.bone_rest, avatar.pose_bones)
    np.testing.assert_allclose(truth.influences, group_influences(raw, avatar.bone_groups), atol=1e-6)
    for p, name in enumerate(avatar.pose_names):
        held = truth.pose_frames(name)
        members = _moving(avatar, p)
        # A bone group all of whose members move in the pose has influence exactly 1 there.
        full = np.array([members[avatar.bone_groups == g].all() for g in avatar.bone_groups]) & members
        np.testing.assert_allclose(truth.influences[held][:, p, full], 1.0, atol=1e-5)
        # Its region influence is largest there for the region the pose wrinkles most.
        assert truth.region_influence[held][:, :, p].max() > 0.3
    np.testing.assert_array_equal(truth.influences[truth.pose_frames("neutral")], 0.0)


@pytest.mark.parametrize("seed", range(5))
def test_head_pose_within_limits(avatar, seed):
    from capture2face.camera import framing_pose

    perf = random_performance(avatar, 200, seed=seed)
    yaw, pitch, roll = np.abs(perf.head_angles).max(0)
    assert yaw <= YAW_LIMIT + 1e-4 and pitch <= PITCH_LIMIT + 1e-4 and roll <= ROLL_LIMIT + 1e-4
    assert np.abs(perf.head_angles).max() > 5.0  # the head does move
    # The pose is framing_pose at those angles, translated by the small offset.
    for f in (0, 77, 199):
        expect = framing_pose(avatar, *perf.head_angles[f], fov_y_degrees=perf.fov_y)
        expect[:3, 3] += perf.head_offset[f]
        np.testing.assert_allclose(perf.head_pose[f], expect, atol=1e-4)
    assert np.abs(perf.head_offset).max() < 0.1 * avatar.face_size()
    # Light stays in front of the face.
    assert np.all(perf.light_direction[:, 2] > 0.5)
    np.testing.assert_allclose(np.linalg.norm(perf.light_direction, axis=1), 1.0, atol=1e-5)


def test_head_motion_only_and_frontal_options(avatar):
    still = random_performance(avatar, 90, seed=1, expression=False)
    assert np.ptp(still.bone_positions, axis=0).max() == 0 and np.ptp(still.blend_weights, axis=0).max() == 0
    assert np.abs(still.bone_positions[0] - avatar.bone_rest).max() > 0.05  # mild, not neutral
    assert np.ptp(still.head_angles, axis=0).max() > 5.0
    frontal = random_performance(avatar, 90, seed=1, head_motion=False)
    assert np.all(frontal.head_angles == 0) and np.ptp(frontal.head_pose, axis=0).max() == 0


def test_deterministic_for_a_seed(avatar):
    a, b = random_performance(avatar, 60, seed=11), random_performance(avatar, 60, seed=11)
    c = random_performance(avatar, 60, seed=12)
    for name in ("bone_positions", "blend_weights", "head_pose", "light_direction", "key_pose"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.bone_positions, c.bone_positions)


def test_face_exit_marks_frames_without_a_face(avatar):
    perf = random_performance(avatar, 120, seed=2, face_exit=True)
    truth = compute_truth(avatar, perf, 256, 256)
    gone = np.flatnonzero(~truth.face_visible)
    assert 20 <= len(gone) <= 45  # about a second at 30 fps
    assert np.all(np.diff(gone) == 1)  # one contiguous gap
    assert truth.face_visible[:30].all() and truth.face_visible[-30:].all()
    # Where the face is gone, every canonical landmark is outside the image.
    xs = truth.landmarks_px[gone[len(gone) // 2], :468, 0]
    assert np.all(xs > 256)


# ---- rendered clips (the session fixture ``synthetic_clip`` in conftest.py) ------------

def test_truth_file_beside_the_video(synthetic_clip):
    assert synthetic_clip.truth_path == truth_path(synthetic_clip.video_path)
    loaded = SyntheticTruth.load(synthetic_clip.truth_path)
    for name in ("landmarks_px", "bone_positions", "influences", "head_pose", "region_influence"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(synthetic_clip.truth, name))
    assert loaded.pose_names == synthetic_clip.truth.pose_names
    assert loaded.landmarks_px.shape == (loaded.n_frames, 478, 2)


def test_truth_landmarks_are_the_renderers_projection(synthetic_clip):
    from capture2face.camera import project

    t = synthetic_clip.truth
    expect = project(t.landmarks_head, t.head_pose, t.fov_y, (t.width, t.height))
    np.testing.assert_allclose(t.landmarks_px, expect, atol=1e-3)
    assert np.isfinite(t.landmarks_px[:, :468]).all()


def test_truth_landmarks_lie_on_the_rendered_face(avatar, synthetic_clip):
    """Render frames on a background of a colour the face never has; the projected
    canonical landmarks must land on face pixels, and pixels far outside them on
    background."""
    from capture2face.render import Renderer, RenderOptions

    t = synthetic_clip.truth
    bg = (0.0, 1.0, 0.0)
    opts = RenderOptions(size=(t.width, t.height), wrinkles="auto", fov_y_degrees=t.fov_y, background=bg)
    frames = [0, t.n_frames // 2, t.n_frames - 1]
    with Renderer.create_from_options(avatar, opts) as renderer:
        images = dict(zip(frames, render_performance(t, renderer, frames)))
    for f in frames:
        img = images[f].astype(int)
        background = (img[..., 1] > 200) & (img[..., 0] < 40) & (img[..., 2] < 40)
        px = np.floor(t.landmarks_px[f, :468]).astype(int)
        on_face = ~background[px[:, 1], px[:, 0]]
        assert on_face.mean() >= 0.97, (f, on_face.mean())
        # A box twice the landmarks' size around them holds all the face; the corners are background.
        assert background[0, 0] and background[-1, -1]
        # The face region in the image has the size of the projected landmarks.
        lo, hi = t.landmarks_px[f, :468].min(0), t.landmarks_px[f, :468].max(0)
        ys, xs = np.nonzero(~background)
        assert xs.min() < lo[0] + 3 and xs.max() > hi[0] - 3 and ys.min() < lo[1] + 3


def test_same_seed_same_first_frame(avatar, synthetic_clip):
    from capture2face.render import Renderer, RenderOptions
    from capture2face.synth import make_performance

    t = synthetic_clip.truth
    opts = SynthOptions(frames=t.n_frames, seed=0, size=t.width)
    again = compute_truth(avatar, make_performance(avatar, opts), t.width, t.height)
    for name in ("bone_positions", "blend_weights", "head_pose", "landmarks_px", "influences", "light_direction"):
        np.testing.assert_array_equal(getattr(again, name), getattr(t, name))
    ropts = RenderOptions(size=t.width, wrinkles="auto", fov_y_degrees=t.fov_y)
    firsts = []
    for truth in (t, again):
        with Renderer.create_from_options(avatar, ropts) as renderer:
            firsts.append(next(render_performance(truth, renderer, [0])))
    np.testing.assert_array_equal(firsts[0], firsts[1])
    # The video holds that frame (up to H.264's loss).
    import av

    with av.open(synthetic_clip.video_path) as container:
        decoded = next(container.decode(video=0)).to_ndarray(format="rgb24")
    assert np.abs(decoded.astype(int) - firsts[0].astype(int)).mean() < 3.0


def _mediapipe_landmarks(video_path, times):
    """(F, 478, 2) pixel landmarks from MediaPipe's Face Landmarker in VIDEO mode at the
    frame times ``times`` (F,) seconds (NaN where it finds no face)."""
    import av
    import mediapipe as mp
    from mediapipe.tasks.python import BaseOptions, vision

    from capture2face.models.face_model import find_face_model

    options = vision.FaceLandmarkerOptions(
        base_options=BaseOptions(model_asset_path=str(find_face_model())),
        running_mode=vision.RunningMode.VIDEO, num_faces=1,
    )
    out = []
    with vision.FaceLandmarker.create_from_options(options) as lm, av.open(str(video_path)) as container:
        for i, frame in enumerate(container.decode(video=0)):
            rgb = frame.to_ndarray(format="rgb24")
            res = lm.detect_for_video(mp.Image(image_format=mp.ImageFormat.SRGB, data=rgb), int(round(times[i] * 1000)))
            h, w = rgb.shape[:2]
            if res.face_landmarks:
                out.append([(p.x * w, p.y * h) for p in res.face_landmarks[0]])
            else:
                out.append(np.full((478, 2), np.nan))
    return np.asarray(out, np.float64)


def test_mediapipe_tracks_the_synthetic_clip(synthetic_clip):
    t = synthetic_clip.truth
    found = _mediapipe_landmarks(synthetic_clip.video_path, t.times)
    assert len(found) == t.n_frames
    tracked = np.isfinite(found[:, 0, 0])
    assert tracked.mean() >= 0.95, tracked.mean()
    # And it finds the face where the truth says it is (normalised by the inter-ocular
    # distance): a wrong projection or a face the tracker misreads shows up here.
    iod = np.linalg.norm(t.landmarks_px[:, IOD_PAIR[0]] - t.landmarks_px[:, IOD_PAIR[1]], axis=1)
    err = np.linalg.norm(found[:, :468] - t.landmarks_px[:, :468], axis=2).mean(1) / iod
    assert np.nanmedian(err[tracked]) < 0.05, np.nanmedian(err[tracked])


def test_performances_that_do_not_start_at_rest(avatar):
    """``start="held"``: frame 0 holds an expression away from rest for the first second or
    more; ``start="raised"``: the brows sit above their rest height from frame 0 on most
    frames. Both keep an exact neutral hold, mid-clip, and the reference-pose holds."""
    from capture2face.measures import MEASURES, character_measures, character_rest_measures

    brows = [list(MEASURES).index("brow_right"), list(MEASURES).index("brow_left")]
    rest_brow = character_rest_measures(avatar)[brows].mean()
    for start in ("held", "raised"):
        perf = random_performance(avatar, 240, seed=0, start=start)
        neutral = np.flatnonzero(perf.key_pose == KEY_NEUTRAL)
        assert len(neutral) >= 3 and 0.3 * 240 < neutral[0] < 0.8 * 240, start
        np.testing.assert_array_equal(perf.bone_positions[neutral[0]], avatar.bone_rest)
        assert all(np.any(perf.key_pose == KEY_POSE0 + p) for p in range(len(avatar.pose_names)))
        assert np.abs(perf.bone_positions[0] - avatar.bone_rest).max() > 0.3, start  # cm: not at rest
        brow = character_measures(avatar, perf.bone_positions, perf.blend_weights)[:, brows].mean(1) - rest_brow
        if start == "held":
            same = np.abs(perf.bone_positions - perf.bone_positions[0]).max(axis=(1, 2)) < 1e-6
            assert same[:30].all()  # held for at least a second at 30 fps
        else:
            assert brow[0] > 0.05  # IOD above rest
            assert np.mean(brow > 0.02) > 0.8  # raised on most frames
            assert abs(brow[neutral]).max() < 1e-6
    rest = random_performance(avatar, 240, seed=0)
    assert rest.key_pose[0] == KEY_NEUTRAL and np.mean(
        character_measures(avatar, rest.bone_positions, rest.blend_weights)[:, brows].mean(1) - rest_brow > 0.02) < 0.6
    with pytest.raises(CaptureError):
        random_performance(avatar, 240, start="sideways")

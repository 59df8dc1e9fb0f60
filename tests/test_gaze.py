"""Gaze: eyes that turn (rig, renderer, glTF), gaze from the tracked irises, Live Link columns."""

from __future__ import annotations

import csv

import numpy as np

from capture2face.retarget.gaze import HUMAN_RADIUS_IOD, eye_radius_iod, eye_rotation
from capture2face.synth.truth import deformed_landmarks
from tests.helpers import make_animation, validate


def _gaze_clip(rig, frames=60, seed=3):
    """Rest face, both eyes wandering (yaw +-25, pitch +-15 degrees) after 5 frames
    straight ahead (the neutral hold)."""
    rng = np.random.default_rng(seed)
    t = np.clip(np.linspace(-0.1, 1.0, frames), 0.0, None)[:, None]
    yaw = 25.0 * np.sin(2 * np.pi * t * rng.uniform(1, 2, 2))
    pitch = 15.0 * np.sin(2 * np.pi * t * 1.3) * np.ones((1, 2))
    truth = np.stack([yaw, pitch], -1)  # (F, 2, 2)
    bones = np.repeat(rig.bone_rest[None], frames, 0)
    weights = np.zeros((frames, rig.n_morphs), np.float32)
    return truth, bones, weights


def test_gaze_from_exact_irises_recovers_the_angles(avatar):
    truth, bones, weights = _gaze_clip(avatar)
    lm = deformed_landmarks(avatar, bones, weights, eye_rotation=truth)
    est = eye_rotation(lm, lm[0], eye_radius_iod(avatar))
    assert est.shape == truth.shape and est.dtype == np.float32
    # Pitch is the two eyes' mean (equal here); the iris mean sits on the eye's sphere
    # direction, so the angles come back to within rounding.
    assert np.abs(est - truth).max() < 0.05
    # A human's smaller eye radius reads the same motion as larger angles.
    human = eye_rotation(lm, lm[0], HUMAN_RADIUS_IOD)
    moving = np.abs(truth[..., 0]) > 5
    assert np.all(np.abs(human[..., 0][moving]) > np.abs(truth[..., 0][moving]))


def test_gaze_survives_blinks(avatar):
    truth, bones, weights = _gaze_clip(avatar)
    blink_r, blink_l = avatar.morph_index("eyeBlinkRight"), avatar.morph_index("eyeBlinkLeft")
    weights[20:26, blink_r] = 1.0  # the right eye winks: it takes the left eye's angles
    weights[40:44, [blink_r, blink_l]] = 1.0  # both blink: bridged from the frames around
    lm = deformed_landmarks(avatar, bones, weights, eye_rotation=truth)
    est = eye_rotation(lm, lm[0], eye_radius_iod(avatar))
    np.testing.assert_array_equal(est[20:26, 0], est[20:26, 1])
    np.testing.assert_allclose(est[20:26, 1], truth[20:26, 1], atol=0.05)
    bridge = np.array([np.interp(np.arange(40, 44), [39, 44], est[[39, 44], e, c]) for e in (0, 1) for c in (0, 1)])
    np.testing.assert_allclose(est[40:44].transpose(1, 2, 0).reshape(4, -1), bridge, atol=1e-4)


def test_livelink_eye_columns_come_from_the_gaze(avatar, tmp_path):
    import dataclasses

    from capture2face.export.livelink import ANGLE_UNIT_DEG, HEADER, write_livelink_csv

    anim = make_animation(avatar, frames=20)
    truth, _, _ = _gaze_clip(avatar, frames=20)
    anim = dataclasses.replace(anim, eye_rotation=truth.astype(np.float32))
    path = tmp_path / "ll.csv"
    write_livelink_csv(anim, None, path)
    cols = HEADER.split(",")
    rows = np.array([[float(v) for v in r[2:]] for r in csv.reader(path.read_text().splitlines()[1:])])
    col = {n: i - 2 for i, n in enumerate(cols)}
    np.testing.assert_allclose(rows[:, col["LeftEyeYaw"]], truth[:, 1, 0] / ANGLE_UNIT_DEG, atol=2e-6)
    np.testing.assert_allclose(rows[:, col["LeftEyePitch"]], truth[:, 1, 1] / ANGLE_UNIT_DEG, atol=2e-6)
    np.testing.assert_allclose(rows[:, col["RightEyeYaw"]], truth[:, 0, 0] / ANGLE_UNIT_DEG, atol=2e-6)
    np.testing.assert_allclose(rows[:, col["RightEyePitch"]], truth[:, 0, 1] / ANGLE_UNIT_DEG, atol=2e-6)
    assert np.all(rows[:, col["LeftEyeRoll"]] == 0) and np.all(rows[:, col["RightEyeRoll"]] == 0)


def test_animation_glb_turns_the_eye_joints(avatar, tmp_path):
    import dataclasses

    from scipy.spatial.transform import Rotation

    from capture2face.gltf import export_glb, import_glb
    from capture2face.gltf.animation_export import read_glb_animation
    from capture2face.rig.face_rig import eye_rotation_matrices

    truth, _, _ = _gaze_clip(avatar, frames=20)
    anim = dataclasses.replace(make_animation(avatar, frames=20), eye_rotation=truth.astype(np.float32))
    path = tmp_path / "a.glb"
    export_glb(avatar, path, animation=anim)
    report = validate(path)
    assert report["issues"]["numErrors"] == 0 and report["issues"]["numWarnings"] == 0
    back = read_glb_animation(path)
    assert back.joint_names == avatar.bone_names  # the eye joints are no bones
    for side in (0, 1):
        expect = Rotation.from_matrix(eye_rotation_matrices(truth[:, side])).as_quat()
        assert np.abs(np.abs((expect * back.eye_rotation[:, side]).sum(1)) - 1).max() < 1e-6
    # The character comes back with its turning eyes and its bones' skinning.
    rig = import_glb(path)
    assert rig.bone_names == avatar.bone_names
    np.testing.assert_array_equal(rig.eye_vertex_side, avatar.eye_vertex_side)
    np.testing.assert_allclose(rig.eye_centres, avatar.eye_centres, atol=1e-6)
    np.testing.assert_array_equal(rig.skin_joints, avatar.skin_joints)


def test_fidelity_judges_eye_yaw_against_the_eyelook_scores():
    from capture2face.eval.fidelity import summary_line
    from capture2face.measures import GAZE_CHECKS, ClipFidelity

    T = 200
    t = np.arange(T) / 30.0
    rng = np.random.default_rng(0)
    look = np.sin(2 * np.pi * 0.4 * t)  # the tracker's in/out difference, std ~0.7
    gaze = np.zeros((T, 2, 2))
    gaze[:, 0, 0] = 25 * look + rng.normal(0, 3, T)  # right eye follows
    gaze[:, 1, 0] = rng.normal(0, 10, T)  # left eye does not
    scores = np.stack([look, look, 0.01 * look, 0.01 * look], 1)  # pitch: the gaze barely moves
    z = np.zeros((T, 6))
    fid = ClipFidelity(name="x", times=t, source=z, character=z, direct=z, arkit=np.zeros((T, 0)),
                       arkit_names=[], arkit_source="animation", gaze=gaze, gaze_scores=scores)
    fig = fid.figures()["gaze"]
    assert list(fig) == list(GAZE_CHECKS)
    assert fig["yaw_right"]["judged"] and fig["yaw_right"]["met"] and fig["yaw_right"]["r"] > 0.95
    assert fig["yaw_left"]["judged"] and not fig["yaw_left"]["met"]
    assert not fig["pitch_right"]["judged"] and "met" not in fig["pitch_right"]
    line = summary_line([{"summary": {"judged": 0, "faithful": 0, "not_worse_than_direct": 0}, "arkit": {},
                          "gaze": fig}])
    assert "eye yaw 1/2 follows" in line

"""animation.glb and livelink.csv writers (issue 6's exports)."""

from __future__ import annotations

import csv
import dataclasses
import re

import numpy as np
import pytest

from capture2face.errors import CaptureError
from capture2face.export.livelink import HEADER, head_angles, timecodes, write_livelink_csv
from capture2face.gltf import export_glb, import_glb
from capture2face.gltf.animation_export import head_rotations, read_animation_keyframe_count, read_glb_animation
from capture2face.topology import BLENDSHAPE_NAMES
from tests.helpers import make_animation, problems, rot_x, rot_y, rot_z, validate

# Copied character for character from issue 6.
ISSUE_HEADER = (
    "Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,"
    "EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,"
    "EyeLookUpRight,EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,"
    "MouthFunnel,MouthPucker,MouthRight,MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,"
    "MouthFrownRight,MouthDimpleLeft,MouthDimpleRight,MouthStretchLeft,MouthStretchRight,MouthRollLower,"
    "MouthRollUpper,MouthShrugLower,MouthShrugUpper,MouthPressLeft,MouthPressRight,MouthLowerDownLeft,"
    "MouthLowerDownRight,MouthUpperUpLeft,MouthUpperUpRight,BrowDownLeft,BrowDownRight,BrowInnerUp,"
    "BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,CheekSquintLeft,CheekSquintRight,NoseSneerLeft,"
    "NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,LeftEyePitch,LeftEyeRoll,RightEyeYaw,"
    "RightEyePitch,RightEyeRoll"
)


@pytest.fixture(scope="module")
def performance(avatar):
    return make_animation(avatar, t0=2.5)  # clip times need not start at 0


@pytest.fixture(scope="module")
def animation_glb(avatar, performance, tmp_path_factory):
    path = tmp_path_factory.mktemp("anim") / "animation.glb"
    export_glb(avatar, path, animation=performance)
    return path


# ---- animation.glb -------------------------------------------------------------------------
def test_animation_glb_passes_khronos_validator(animation_glb, performance, avatar):
    report = validate(animation_glb)
    assert report["issues"]["numErrors"] == 0, problems(report, 0)
    assert report["issues"]["numWarnings"] == 0, problems(report, 1)
    assert report["info"]["animationCount"] == 1


def test_animation_glb_has_a_keyframe_per_frame_and_the_performance(animation_glb, performance, avatar):
    assert read_animation_keyframe_count(animation_glb) == performance.n_frames
    anim = read_glb_animation(animation_glb)
    np.testing.assert_allclose(anim.times, performance.times - performance.times[0], atol=1e-6)
    assert anim.joint_names == avatar.bone_names and anim.target_names == avatar.morph_names
    # Joint translations compose back to the bone positions (cm) ...
    assert np.abs(anim.bone_positions - performance.bone_positions).max() < 1e-4
    # ... morph weights are the animation's, and the root turns as the head pose does.
    np.testing.assert_array_equal(anim.weights, performance.blend_weights)
    from scipy.spatial.transform import Rotation

    expect = Rotation.from_matrix(performance.head_pose[:, :3, :3].astype(np.float64)).as_quat()
    assert np.abs(np.abs((expect * anim.root_rotation).sum(1)) - 1).max() < 1e-6
    # The animated .glb is still the same character.
    back = import_glb(animation_glb)
    assert np.all(np.abs(back.vertices - avatar.vertices) <= np.spacing(np.abs(avatar.vertices)))


def test_fps_option_and_non_increasing_times(avatar, performance, tmp_path):
    path = tmp_path / "a.glb"
    export_glb(avatar, path, animation=performance, fps=10.0)
    np.testing.assert_allclose(read_glb_animation(path).times, np.arange(performance.n_frames) / 10.0, atol=1e-6)
    stuck = make_animation(avatar, frames=6)
    stuck.times = np.zeros(6)  # a broken clip clock: fall back to frame / fps
    export_glb(avatar, path, animation=stuck)
    np.testing.assert_allclose(read_glb_animation(path).times, np.arange(6) / stuck.fps, atol=1e-6)
    empty = make_animation(avatar, frames=0)
    with pytest.raises(CaptureError, match="no frames"):
        export_glb(avatar, tmp_path / "empty.glb", animation=empty)
    assert not (tmp_path / "empty.glb").exists()


def test_head_rotations_match_scipy_on_all_branches():
    from scipy.spatial.transform import Rotation

    rots = Rotation.random(400, random_state=7)
    pose = np.tile(np.eye(4), (400, 1, 1))
    pose[:, :3, :3] = rots.as_matrix() * 3.0  # a scaled rotation: only the rotation counts
    q = head_rotations(pose)
    assert np.abs(np.abs((q * rots.as_quat()).sum(1)) - 1).max() < 1e-9
    assert (np.einsum("ij,ij->i", q[1:], q[:-1]) >= 0).all()  # sign-continuous for slerp


def test_nearest_rotation_takes_out_scale_shear_and_reflection():
    """The one SVD orthonormalization behind rotation_part, the character export's head
    joint parent and Live Link's head angles."""
    from scipy.spatial.transform import Rotation

    from capture2face.maths.rotations import nearest_rotation, rotation_part

    r = Rotation.random(5, random_state=3).as_matrix()
    np.testing.assert_allclose(nearest_rotation(r * 2.5), r, atol=1e-12)  # batched
    np.testing.assert_allclose(nearest_rotation(r[0] * 0.01), r[0], atol=1e-12)  # one matrix
    mirrored = nearest_rotation(r[1] @ np.diag([1.0, 1.0, -1.0]))
    assert np.linalg.det(mirrored) == pytest.approx(1.0)  # a reflection becomes a rotation
    bad = np.stack([r[2], np.full((3, 3), np.nan), np.zeros((3, 3))])
    np.testing.assert_allclose(rotation_part(bad), [r[2], np.eye(3), np.eye(3)], atol=1e-12)


# ---- livelink.csv ---------------------------------------------------------------------------
def test_livelink_csv_header_rows_and_values(avatar, performance, tmp_path):
    assert HEADER == ISSUE_HEADER
    path = tmp_path / "livelink.csv"
    write_livelink_csv(performance, None, path)
    text = path.read_text()
    lines = text.splitlines()
    assert lines[0] == ISSUE_HEADER
    assert len(lines) == 1 + performance.n_frames
    rows = list(csv.reader(lines[1:]))
    assert all(len(r) == 63 and r[1] == "61" for r in rows)
    assert all(re.fullmatch(r"\d\d:\d\d:\d\d:\d\d\.\d\d\d", r[0]) for r in rows)
    assert rows[0][0] == "00:00:02:15.000" and rows[1][0] == "00:00:02:16.000"  # t = 2.5 s at 30 fps
    cols = ISSUE_HEADER.split(",")
    values = np.array([[float(v) for v in r[2:]] for r in rows])
    col = {n: i - 2 for i, n in enumerate(cols)}
    mp = {n: i for i, n in enumerate(BLENDSHAPE_NAMES)}
    # By name, every blendshape column is the animation's ARKit curve, never the
    # character's own morph weight of that name (which shares its motion with the bones).
    assert "jawOpen" in avatar.morph_names and "tongueOut" not in BLENDSHAPE_NAMES
    np.testing.assert_allclose(values[:, col["JawOpen"]], performance.arkit_weights[:, mp["jawOpen"]], atol=1e-6)
    assert np.abs(values[:, col["JawOpen"]] - performance.blend_weights[:, avatar.morph_index("jawOpen")]).max() > 0.1
    for c in cols[2:53]:
        np.testing.assert_allclose(values[:, col[c]], performance.arkit_weights[:, mp[c[0].lower() + c[1:]]], atol=1e-6)
    assert np.all(values[:, col["TongueOut"]] == 0)
    # Head angles: normalized, 1 = 90 degrees.
    t = performance.times
    np.testing.assert_allclose(values[:, col["HeadYaw"]], 0.4 * np.sin(2 * np.pi * 0.5 * t) / (np.pi / 2), atol=2e-6)
    np.testing.assert_allclose(values[:, col["HeadPitch"]], 0.2 * np.sin(2 * np.pi * 0.7 * t) / (np.pi / 2), atol=2e-6)
    np.testing.assert_allclose(values[:, col["HeadRoll"]], 0.1 * np.cos(t) / (np.pi / 2), atol=2e-6)
    # Eye yaw from eyeLook*: left eye looking out (and right eye looking in) = towards +x.
    s = performance.mediapipe_blendshapes
    np.testing.assert_allclose(values[:, col["LeftEyeYaw"]],
                               (s[:, mp["eyeLookOutLeft"]] - s[:, mp["eyeLookInLeft"]]) / 3, atol=2e-6)
    np.testing.assert_allclose(values[:, col["RightEyeYaw"]],
                               (s[:, mp["eyeLookInRight"]] - s[:, mp["eyeLookOutRight"]]) / 3, atol=2e-6)
    assert np.all(values[:, col["LeftEyeRoll"]] == 0)


def test_livelink_takes_scores_from_a_track_like_source(avatar, performance, tmp_path):
    names = [n.upper() for n in BLENDSHAPE_NAMES]  # matching is case-insensitive
    scores = np.full((performance.n_frames, len(names)), 0.25, np.float32)
    path = tmp_path / "ll.csv"
    cols = ISSUE_HEADER.split(",")
    blend = list(range(2, 53))  # every column but TongueOut
    # The scores drive the eye angles; the blendshape columns stay the ARKit curves.
    write_livelink_csv(performance, (scores, names), path)
    rows = list(csv.reader(path.read_text().splitlines()[1:]))
    assert {r[i] for r in rows for i in blend} != {"0.250000"}
    assert {r[cols.index("LeftEyeYaw")] for r in rows} == {"0.000000"}
    # An animation saved before it had ARKit curves: the given scores fill the columns,
    # still never the character's morph weights.
    old = dataclasses.replace(performance, arkit_names=[], arkit_weights=None)
    write_livelink_csv(old, (scores, names), path)
    rows = list(csv.reader(path.read_text().splitlines()[1:]))
    assert {r[i] for r in rows for i in blend} == {"0.250000"}
    with pytest.raises(CaptureError, match="blendshape frames"):
        write_livelink_csv(performance, (scores[:3], names), path)


def test_head_angles_and_timecodes():
    pose = np.tile(np.eye(4), (3, 1, 1))
    pose[0, :3, :3] = rot_y(0.5)  # face turns to the subject's left
    pose[1, :3, :3] = rot_x(0.3)  # face tips down (+z towards -y)
    pose[2, :3, :3] = rot_y(-0.2) @ rot_x(0.1) @ rot_z(0.3)
    np.testing.assert_allclose(head_angles(pose), [[0.5, 0, 0], [0, 0.3, 0], [-0.2, 0.1, 0.3]], atol=1e-12)
    assert timecodes(np.array([0.0, 1 / 30, 59.99, 3661.5, 1 / 60]), 30.0) == [
        "00:00:00:00.000", "00:00:00:01.000", "00:00:59:29.700", "01:01:01:15.000", "00:00:00:00.500"]
    assert timecodes(np.arange(3) / 25.0, 25.0)[2] == "00:00:00:02.000"


def test_untracked_head_poses_become_identity():
    pose = np.zeros((3, 4, 4))
    pose[1] = np.nan
    pose[2, :3, :3] = rot_y(0.3)
    np.testing.assert_allclose(head_angles(pose), [[0, 0, 0], [0, 0, 0], [0.3, 0, 0]], atol=1e-12)
    q = head_rotations(pose)
    np.testing.assert_allclose(q[:2], [[0, 0, 0, 1], [0, 0, 0, 1]], atol=1e-12)

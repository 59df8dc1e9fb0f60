"""Closed loop on a short synthetic clip: render -> track -> retarget -> compare with truth.

The full benchmark (``capture2face eval synthetic``, 300 frames at 512 px) has tighter
goals; here a 60-frame clip at 320 px keeps the suite fast, with looser bounds.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from capture2face.evaluate import evaluate_track, local_rest_maps, synthetic_case, truth_on_target
from capture2face.rig.avatar import default_avatar


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    return synthetic_case(frames=60, seed=1, size=320, folder=tmp_path_factory.mktemp("eval"), progress=False)


@pytest.fixture(scope="module")
def same(case):
    clip, track = case
    return evaluate_track(track, clip.truth)


@pytest.fixture(scope="module")
def cross(case):
    clip, track = case
    return evaluate_track(track, clip.truth, target_variant="wide")


def test_same_character_figures(same):
    assert same["frames"] == 60 and same["frames_scored"] >= 55
    assert same["landmark_nme_iod"] < 0.08
    assert same["bone_error_iod_median"] < 0.04
    assert same["bone_error_iod_p95"] < 0.10
    # Better than predicting the rest pose where it matters (large motions) ...
    assert same["bone_error_iod_p95"] < same["baseline_rest_bone_error_iod_p95"]
    # ... and than all-zero influences, per vertex (what is rendered) and per bone.
    assert same["wrinkle_influence_mae"] < 0.6 * same["baseline_zero_influence_mae"]
    assert same["wrinkle_influence_mae_bone"] < 0.7 * same["baseline_zero_influence_mae_bone"]
    assert same["blendweight_mae"] < 0.1
    assert same["neutral_bone_offset_cm"] == 0.0
    json.dumps(same)  # plain JSON types only


def test_cross_character_neutral_and_scale(cross, same):
    assert cross["target"] == "default_wide"
    assert cross["neutral_bone_offset_cm"] == 0.0
    assert cross["bone_error_iod_median"] < 0.04
    assert cross["bone_error_iod_p95"] < cross["baseline_rest_bone_error_iod_p95"]
    # Motion on the larger face is not smaller than on the source.
    assert cross["motion_scale_ratio"] > 0.8


def test_truth_on_target_is_identity_on_same_rig_and_exact_at_rest():
    rig, wide = default_avatar(), default_avatar(variant="wide")
    bones = np.repeat(rig.bone_rest[None], 2, 0).astype(np.float64)
    np.testing.assert_allclose(truth_on_target(bones, rig, wide), np.repeat(wide.bone_rest[None], 2, 0), atol=1e-6)
    np.testing.assert_array_equal(truth_on_target(bones, rig, rig), bones)
    # A rig against itself: every local map is the identity.
    np.testing.assert_allclose(local_rest_maps(rig, rig), np.broadcast_to(np.eye(3), (rig.n_bones, 3, 3)), atol=1e-6)
    # The wide variant is wider: sideways motion is stretched for the cheek bones.
    maps = local_rest_maps(rig, wide)
    assert maps[rig.bone_index("cheek_L"), 0, 0] > 1.05


def test_cli_eval_synthetic_writes_json(tmp_path):
    from capture2face.cli import main

    out = tmp_path / "eval.json"
    assert main(["-q", "eval", "synthetic", "--frames", "40", "--size", "256", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    for key in ("landmark_nme_iod", "bone_error_iod_median", "bone_error_iod_p95", "blendweight_mae",
                "mediapipe_blendshape_mae", "wrinkle_influence_mae", "frames"):
        assert np.isfinite(result[key]), key
    assert result["frames"] == 40

"""Closed loop on a short synthetic clip: render -> track -> retarget -> compare with truth.

The full benchmark (``capture2face eval synthetic``, 300 frames at 512 px) has tighter
goals; here a 60-frame clip at 320 px keeps the suite fast, with looser bounds.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from capture2face.eval.synthetic import evaluate_track, local_rest_maps, summary_line, synthetic_case, truth_on_target
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
    return evaluate_track(track, clip.truth, target_variant="wide", auto_neutral=False)


def test_same_character_figures(same, case):
    """Each accuracy figure against its trivial prediction (rest bones, all-zero weights,
    zero influences): an absolute bound alone can be met by predicting nothing (on this
    clip the rest pose's median bone error is 0.038 IOD, under the 0.04 bound)."""
    assert same["frames"] == 60 and same["frames_scored"] >= 55
    assert same["landmark_nme_iod"] < 0.08
    # Bones: clearly better than the rest pose at the median and at the large motions
    # (about 0.7 of it today; the 300-frame goal is 0.6 at p95).
    assert same["bone_error_iod_median"] < 0.04
    assert same["bone_error_iod_median_ratio"] < 0.85
    assert same["bone_error_iod_p95_ratio"] < 0.85
    assert same["bone_error_iod_mean_ratio"] < 0.85
    # Influences: per vertex (what is rendered) and per bone, against all zeros.
    assert same["wrinkle_influence_mae_ratio"] < 0.6
    assert same["wrinkle_influence_mae_bone_ratio"] < 0.7
    assert same["region_influence_mae_ratio"] < 0.6
    # Blend weights. Over all morphs the solved weights are WORSE than all zeros today
    # (blendweight_mae_ratio about 1.35: small weights spread over morphs the clip never
    # uses, and eyeWide* anti-correlated with the truth), so an MAE bound would pass a
    # broken solve. What holds and is a real check: on the morphs the clip moves, the
    # solve is closer than all zeros and follows them (all zeros, or any constant, scores
    # r = 0); jawOpen and mouthPucker are followed closely. Tighten to the goal (ratio < 1
    # and active r >= 0.6) when the solve gets there.
    assert same["blendweight_active_morphs"] >= 5
    # All weights: the all-zero prediction's MAE is the truth's mean weight (known from
    # the clip's truth); the solve's MAE is bounded, and within 1.5x of that (1.26x today).
    clip, track = case
    assert same["baseline_zero_blendweight_mae"] == pytest.approx(np.abs(clip.truth.blend_weights).mean(), rel=1e-5)
    assert same["blendweight_mae"] < 0.085
    assert same["blendweight_mae"] < 1.5 * same["baseline_zero_blendweight_mae"]
    # Errors on the active morphs are part of the MAE over all of them.
    n_morphs = clip.truth.blend_weights.shape[1]
    assert same["blendweight_mae"] >= same["blendweight_active_mae"] * same["blendweight_active_morphs"] / n_morphs
    # (0.86-0.89 with the synthetic-tuned landmark filter; 0.94-0.98 with the real-clip
    # one, which lets more of the tracker's noise through on the rendered avatar.)
    assert same["blendweight_active_mae_ratio"] < 1.0
    assert same["blendweight_active_r"] > 0.15
    per_morph = same["blendweight_active_r_per_morph"]
    assert per_morph["jawOpen"] > 0.7 and per_morph["mouthPucker"] > 0.7
    # The character's mouth opens with the truth's (the rest pose has gain 0, r 0).
    assert same["mouth_open_r"] > 0.9
    assert 0.4 < same["mouth_open_gain"] < 1.5
    assert same["neutral_bone_offset_cm"] == 0.0
    json.dumps(same)  # plain JSON types only


def test_measure_chain_locates_amplitude_loss(same, case):
    """The per-measure chain: the tracker against the truth, the character against both.
    Gains compose (character/truth = character/tracker x tracker/truth, since every std
    is over the same frames), the chain's mouth figure is the headline one, and every
    measure is followed (r well above 0, which the rest pose scores)."""
    chain = same["measures"]
    assert set(chain) == {"mouth_open", "mouth_width", "brow_right", "brow_left", "eye_right", "eye_left"}
    for name, entry in chain.items():
        composed = entry["character_vs_tracker"]["gain"] * entry["tracker"]["gain"]
        assert entry["character"]["gain"] == pytest.approx(composed, rel=1e-9), name
        assert entry["tracker"]["r"] > 0.7 and entry["character"]["r"] > 0.7, name
    assert chain["mouth_open"]["character"]["r"] == pytest.approx(same["mouth_open_r"], abs=1e-9)
    assert chain["mouth_open"]["character"]["gain"] == pytest.approx(same["mouth_open_gain"], rel=1e-9)
    assert f"(tracker's own {chain['mouth_open']['tracker']['gain']:.2f})" in summary_line(same)


def test_auto_neutral_block_and_goals(same, case):
    clip, track = case
    auto = same["auto_neutral"]
    assert auto["neutral_frame"] == same["neutral_frame_auto"] == track.neutral_frame
    assert same["neutral_frame"] == int(clip.truth.pose_frames("neutral")[0])
    # Same keys, except what only the outer block reports.
    assert set(same) - set(auto) == {"auto_neutral", "neutral_frame_auto", "neutral_frame_auto_offset_iod",
                                     "rest_offsets_iod"}
    # The tracker's own rest, region by region: the lids and lips within 0.01 IOD of the
    # truth's neutral (issue 21's goal). The brows miss it on this avatar (0.06 IOD low:
    # MediaPipe scores its frowns as calm brows; docs/rest.md), bounded here.
    offsets = same["rest_offsets_iod"]
    assert set(offsets) == {"lip_gap", "brow_height", "lid_right", "lid_left"}
    assert max(abs(offsets[k]) for k in ("lip_gap", "lid_right", "lid_left")) <= 0.01, offsets
    assert abs(offsets["brow_height"]) < 0.08, offsets
    # Here the tracker picks a frame the truth also holds at neutral, so starting from it
    # costs little; a retarget from a wrong frame would show as a large difference.
    assert same["neutral_frame_auto_offset_iod"] == 0.0
    assert auto["bone_error_iod_p95"] < 1.15 * same["bone_error_iod_p95"]
    assert auto["bone_error_iod_p95_ratio"] < 0.85
    # Goals: judged on the figures, never assumed.
    for block in (same, auto):
        g = block["goals"]
        assert g["bone_p95"]["met"] == (block["bone_error_iod_p95_ratio"] <= 0.6)
        assert g["wrinkles"]["met"] == (block["wrinkle_influence_mae_ratio"] <= 0.5)
        assert g["blendweights"]["met"] == (block["blendweight_mae_ratio"] < 1.0
                                            and block["blendweight_active_r"] >= 0.6)
        assert g["all_met"] == all(g[k]["met"] for k in ("bone_p95", "blendweights", "wrinkles"))
        assert g["frames_as_stated"] is False  # 60 frames; the goals are stated for 300
    line = summary_line(auto, "auto")
    assert line.startswith(f"auto: neutral frame {track.neutral_frame};")
    assert f"goals met {sum(auto['goals'][k]['met'] for k in ('bone_p95', 'blendweights', 'wrinkles'))}/3" in line


def test_cross_character_neutral_and_scale(cross):
    assert cross["target"] == "default_wide"
    assert "auto_neutral" not in cross
    assert cross["neutral_bone_offset_cm"] == 0.0
    # The rest pose's median is 0.036 IOD here: judge against it, not an absolute bound.
    assert cross["bone_error_iod_median_ratio"] < 0.85
    assert cross["bone_error_iod_p95_ratio"] < 0.85
    assert cross["wrinkle_influence_mae_ratio"] < 0.6
    assert cross["mouth_open_r"] > 0.9 and cross["mouth_open_gain"] > 0.4
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
    """The command's figures on a known clip (seed 0, 40 frames, 256 px): the trivial
    predictions' figures equal those computed here from the clip's own truth, and the
    solve beats them."""
    from capture2face.cli import main
    from capture2face.synth import SynthOptions, synthesize

    out = tmp_path / "eval.json"
    assert main(["-q", "eval", "synthetic", "--frames", "40", "--size", "256", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert (result["frames"], result["seed"], result["size"]) == (40, 0, 256)
    assert result["frames_scored"] == 40  # one face, always in view
    # The same clip again (synthesis is deterministic): its truth gives the baselines.
    truth = synthesize(tmp_path / "clip.mp4", SynthOptions(frames=40, seed=0, size=256), progress=False).truth
    rig = default_avatar()
    bones = np.flatnonzero((np.arange(rig.n_bones) > 0) & (np.asarray(rig.bone_landmarks) >= 0))
    rest_err = np.linalg.norm(truth.bone_positions[:, bones] - rig.bone_rest[bones], axis=2) / rig.interocular()
    for block in (result, result["auto_neutral"]):
        assert block["baseline_zero_blendweight_mae"] == pytest.approx(np.abs(truth.blend_weights).mean(), rel=1e-5)
        assert block["baseline_rest_bone_error_iod_median"] == pytest.approx(np.median(rest_err), rel=1e-4)
        assert block["baseline_rest_bone_error_iod_p95"] == pytest.approx(np.percentile(rest_err, 95), rel=1e-4)
        # The solve against those trivial predictions (rest bones, all-zero weights and
        # influences), and the mouth against the truth's (the rest pose: gain 0, r 0).
        assert block["landmark_nme_iod"] < 0.06
        assert block["bone_error_iod_median"] < 0.85 * block["baseline_rest_bone_error_iod_median"]
        assert block["bone_error_iod_p95"] < 0.85 * block["baseline_rest_bone_error_iod_p95"]
        assert block["wrinkle_influence_mae"] < 0.7 * block["baseline_zero_influence_mae"]
        assert block["blendweight_active_mae"] < block["baseline_zero_blendweight_active_mae"]
        # Over all morphs the solve is worse than all zeros today (0.074 against 0.046:
        # small weights spread over morphs the clip never uses): bounded, not compared.
        assert block["blendweight_mae"] < 0.09
        assert block["blendweight_active_r"] > 0.15
        assert block["mouth_open_r"] > 0.9 and 0.4 < block["mouth_open_gain"] < 1.5
        assert block["mediapipe_blendshape_mae"] > 0  # MediaPipe's own scores are not the truth
        assert {"bone_p95", "blendweights", "wrinkles", "all_met"} <= set(block["goals"])
        assert block["goals"]["bone_p95"]["met"] == (block["bone_error_iod_p95_ratio"] <= 0.6)

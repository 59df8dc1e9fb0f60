"""Any ARKit character as the synthetic actor (issue 22): its random ARKit performance, its
truth against what is rendered, and the closed loop's ARKit curves and measures.

The actor is the shared ICT-FaceKit head ict-a (skipped where ../shared/characters is
absent); clips are 60 frames at 320 px to keep the suite fast (the benchmark's figures,
300 frames at 512 px, are in docs/accuracy.md).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from capture2face.character.load import load_character
from capture2face.cli import main
from capture2face.eval.synthetic import arkit_curve_figures
from capture2face.eval.synthetic_actor import evaluate_actor_track, resolve_characters
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import landmark_points
from capture2face.synth import SyntheticTruth, SynthOptions, actor_rig, synthesize
from capture2face.synth.actor import random_arkit_performance
from capture2face.synth.trajectories import KEY_NEUTRAL
from capture2face.topology import IOD_PAIR
from capture2face.tracking import TrackOptions, track_clip
from tests.helpers import shared_character

TOOLS = Path(__file__).resolve().parents[1] / "tools"


@pytest.fixture(scope="module")
def ict_a():
    return actor_rig(load_character(shared_character("ict-a.glb")))


@pytest.fixture(scope="module")
def case(ict_a, tmp_path_factory):
    """(clip, track) of ict-a performing 60 frames at 320 px."""
    folder = tmp_path_factory.mktemp("actor")
    clip = synthesize(folder / "ict.mp4", SynthOptions(frames=60, seed=3, size=320), progress=False, actor=ict_a)
    return clip, track_clip(clip.video_path, TrackOptions(), progress=False)


def _column(rig, name: str) -> int:
    return next(m for m, n in arkit_morphs(rig.morph_names).items() if n == name)


def test_turning_eyes_fit_the_eyeballs(ict_a):
    """The eyeballs' sphere centres lie behind the irises, an eyeball's radius (~1.2 cm)
    away from both the iris landmarks and every vertex of their eyeball."""
    assert ict_a.has_eyes
    for side, iris in ((0, 468), (1, 473)):
        centre = ict_a.eye_centres[side].astype(np.float64)
        ball = ict_a.vertices[ict_a.eye_vertex_side == side].astype(np.float64)
        radius = np.linalg.norm(ball - centre, axis=1)
        assert 0.9 < np.median(radius) < 1.6
        point = landmark_points(ict_a, ict_a.vertices, [iris])[0]
        assert abs(np.linalg.norm(point - centre) - np.median(radius)) < 0.25
        assert point[2] > centre[2] + 0.8  # the iris looks forwards (+z)
    # The subject's right eye (landmark 468) is on -x for a face looking along +z.
    assert ict_a.eye_centres[0, 0] < 0 < ict_a.eye_centres[1, 0]


def test_arkit_performance_is_plausible(ict_a):
    """Neutral held first; smiles with cheek squints, raised brows with wide eyes, speech
    (jawOpen), blinks and the eyeLooks of the gaze; deterministic per seed; bones at rest."""
    perf = random_arkit_performance(ict_a, 300, seed=5)
    w = perf.blend_weights
    col = {n: _column(ict_a, n) for n in ("mouthSmileLeft", "cheekSquintLeft", "browInnerUp", "eyeWideLeft",
                                          "jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthClose",
                                          "eyeLookInRight", "eyeLookOutRight")}
    assert w.min() >= 0.0 and w.max() <= 1.0
    held = np.flatnonzero(perf.key_pose == KEY_NEUTRAL)
    assert held[0] == 0 and len(held) >= 4
    assert np.all(w[held] == 0.0) and np.all(perf.eye_rotation[held] == 0.0)
    assert np.all(perf.bone_positions == ict_a.bone_rest[None])
    assert np.corrcoef(w[:, col["mouthSmileLeft"]], w[:, col["cheekSquintLeft"]])[0, 1] > 0.8
    assert np.corrcoef(w[:, col["browInnerUp"]], w[:, col["eyeWideLeft"]])[0, 1] > 0.6
    for name in ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight"):
        assert np.ptp(w[:, col[name]]) > 0.7, name
    for name in ("mouthSmileLeft", "browInnerUp"):
        assert np.ptp(w[:, col[name]]) > 0.3, name
    # Blinks are brief: the eyes are mostly open.
    assert np.mean(w[:, col["eyeBlinkLeft"]] > 0.5) < 0.15
    assert np.all(w[:, col["mouthClose"]] <= w[:, col["jawOpen"]] + 1e-6)
    # The right eye's yaw (towards +x: inwards) drives eyeLookInRight.
    looks_in = perf.eye_rotation[:, 0, 0] > 3.0
    assert np.all(w[looks_in, col["eyeLookInRight"]] > 0.09) and np.all(w[looks_in, col["eyeLookOutRight"]] == 0)
    again = random_arkit_performance(ict_a, 300, seed=5)
    assert np.array_equal(again.blend_weights, w)
    assert not np.allclose(random_arkit_performance(ict_a, 300, seed=6).blend_weights, w)


def test_truth_is_what_is_rendered(case, ict_a):
    """The truth's landmark points are the rendered mesh's (the renderer's deformer fed the
    truth's weights and gaze), and the tracker finds them in the video."""
    clip, track = case
    truth = SyntheticTruth.load(clip.truth_path)
    assert truth.actor == "ict-a" and truth.blend_names == list(ict_a.morph_names)
    with Renderer.create_from_options(ict_a, RenderOptions(size=64)) as renderer:
        for f in (0, 25, 50):
            drawn = renderer.deformed_positions(FrameState(truth.bone_positions[f], truth.blend_weights[f],
                                                           truth.head_pose[f], eye_rotation=truth.eye_rotation[f]))
            points = landmark_points(ict_a, drawn)
            assert np.abs(points - truth.landmarks_head[f]).max() < 2e-3  # cm
    err = np.linalg.norm(track.landmarks_px[:, :468] - truth.landmarks_px[:, :468], axis=2).mean(1)
    iod = np.linalg.norm(truth.landmarks_px[:, IOD_PAIR[1]] - truth.landmarks_px[:, IOD_PAIR[0]], axis=1)
    assert np.mean(err / iod) < 0.06


def test_ict_actor_onto_default_avatar(case, ict_a):
    """ARKit curves against the truth: jawOpen follows it (r > 0.9, MAE well under the
    all-zero prediction's); the measure chain: the tracker's mouth opening follows the
    actor's true lips, and so does the default avatar's."""
    clip, track = case
    result = evaluate_actor_track(track, clip.truth, ict_a, default_avatar(), auto_neutral=False)
    assert result["actor"] == "ict-a" and result["target"] == "default"
    curves = result["arkit_curves"]
    assert "tongueOut" not in curves and len(curves) == 51  # ict-a: every ARKit name but tongueOut
    assert set(curves["jawOpen"]) == {"r", "mae", "mediapipe_r", "mediapipe_mae", "zero_mae", "moved"}
    jaw = curves["jawOpen"]
    assert jaw["moved"] and jaw["r"] > 0.9 and jaw["mae"] < 0.4 * jaw["zero_mae"]
    mouth = result["measures"]["mouth_open"]
    assert mouth["moved"] and mouth["tracker"]["r"] > 0.9 and mouth["character"]["r"] > 0.9
    assert mouth["tracker"]["gain"] > 0.4 and mouth["character"]["gain"] > 0.4
    assert result["landmark_nme_iod"] < 0.06
    assert result["blendweight_morphs"] == 27  # the default avatar's morphs are all ARKit names
    assert result["blendweight_active_r_per_morph"]["jawOpen"] > 0.9
    assert set(result["goals"]) == {"arkit_curves", "measures", "all_met"}
    assert "jawOpen" in result["goals"]["arkit_curves"]["judged"]


def test_arkit_curve_figures_against_a_perfect_score(case):
    """MediaPipe's scores replaced by the true weights: r 1 and MAE 0 on every curve that
    moves; the all-zero MAE is the truth's mean; ``moved`` is the truth's range >= 0.2."""
    clip, track = case
    truth, names = clip.truth, list(track.blendshape_names)
    perfect = np.array(track.blendshapes, np.float32)
    for m, name in arkit_morphs(truth.blend_names).items():
        if name in names:
            perfect[:, names.index(name)] = truth.blend_weights[:, m]
    use = np.ones(track.n_frames, bool)
    use[:5] = False
    figures = arkit_curve_figures(dataclasses.replace(track, blendshapes=perfect), truth, use)
    for name, f in figures.items():
        w = truth.blend_weights[use, truth.blend_names.index(name)]
        assert f["moved"] == (np.ptp(w) >= 0.2) and f["zero_mae"] == pytest.approx(float(np.mean(w)), abs=1e-6)
        assert f["mediapipe_mae"] < 1e-6
        if f["moved"]:
            assert f["mediapipe_r"] > 0.9999
    assert figures["jawOpen"]["moved"]


def test_ict_actor_onto_another_ict_head(case, ict_a):
    """--target: ict-a onto ict-b (ICT's own _L/_R names, another identity): the truth stays
    the actor's, the measures are ict-b's, its jawOpen weight follows the true one."""
    clip, track = case
    actor, target = resolve_characters(ict_a, shared_character("ict-b.glb"))
    result = evaluate_actor_track(track, clip.truth, actor, target, auto_neutral=False)
    assert result["target"] == "ict-b" and result["blendweight_morphs"] == 51
    assert result["blendweight_active_r_per_morph"]["jawOpen"] > 0.8  # 0.90 here
    assert result["measures"]["mouth_open"]["character"]["r"] > 0.9
    # Same truth, same track: the curves do not depend on the target.
    same = evaluate_actor_track(track, clip.truth, ict_a, default_avatar(), auto_neutral=False)
    assert result["arkit_curves"] == same["arkit_curves"]


def test_cli_synth_actor_and_bad_flags(tmp_path, capsys):
    """``synth --actor`` writes the clip and the actor's truth; the default avatar's
    options that an actor has not are refused with one line (exit 2)."""
    ict = str(shared_character("ict-a.glb"))
    out = tmp_path / "a.mp4"
    assert main(["-q", "synth", "--actor", ict, "--frames", "20", "--size", "128", "-o", str(out)]) == 0
    truth = SyntheticTruth.load(tmp_path / "a.truth.npz")
    assert truth.actor == "ict-a" and truth.n_frames == 20 and truth.eye_rotation is not None
    assert main(["-q", "synth", "--actor", ict, "--start", "held", "-o", str(tmp_path / "b.mp4")]) == 2
    assert main(["-q", "eval", "synthetic", "--actor", ict, "--target-variant", "wide"]) == 2
    assert "--target-variant" in capsys.readouterr().err


def test_cli_eval_synthetic_actor_json(tmp_path):
    """``eval synthetic --actor --target default --json``: the figures' keys."""
    path = tmp_path / "r.json"
    assert main(["-q", "eval", "synthetic", "--actor", str(shared_character("ict-a.glb")), "--target", "default",
                 "--frames", "40", "--size", "256", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["frames"] == 40 and result["target"] == "default" and "auto_neutral" in result
    assert {"arkit_curves", "measures", "goals", "landmark_nme_iod"} <= set(result)
    assert set(result["measures"]["mouth_open"]) >= {"tracker", "character", "moved"}


def test_mirrored_ict_identity_is_the_model_face_for_the_opposite_weights(tmp_path):
    """tools/mirror_identity.py: ict-a + (ict-a - ict-b), with every morph shared, is a third
    ICT identity (the unseen actor of docs/accuracy.md's figures)."""
    a_path, b_path = shared_character("ict-a.glb"), shared_character("ict-b.glb")
    spec = importlib.util.spec_from_file_location("mirror_identity", TOOLS / "mirror_identity.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    tool.mirror_identity(a_path, b_path, tmp_path / "ict-c.glb")
    assert not list(tmp_path.glob("*.partial"))
    a, b, c = (load_character(p) for p in (a_path, b_path, tmp_path / "ict-c.glb"))
    np.testing.assert_allclose(c.vertices, 2 * a.vertices - b.vertices, atol=1e-5)
    assert np.abs(c.vertices - a.vertices).mean() > 0.05  # cm: a face of its own, as far from the neutral as ict-b
    np.testing.assert_array_equal(c.morph_positions, a.morph_positions)
    np.testing.assert_allclose(np.linalg.norm(c.normals, axis=1), 1.0, atol=1e-4)
    assert c.morph_names == a.morph_names and c.landmark_vertices.shape == a.landmark_vertices.shape

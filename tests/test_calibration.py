"""The calibration core: the protocol, finding its steps, the actor's expression mix, actor.json."""

from __future__ import annotations

import json

import numpy as np
import pytest

from capture2face.calibration import PROTOCOL, ActorCalibration, StepFit
from capture2face.calibration.learn import explained_away
from capture2face.calibration.protocol import step_amounts, target_matrix
from capture2face.calibration.segment import Run, align, find_runs
from capture2face.calibration.solve import MAX_WEIGHT, step_weights
from capture2face.errors import CaptureError
from capture2face.topology import ARKIT_NAMES


def test_protocol_steps_one_at_a_time_and_their_targets():
    amounts = step_amounts(30.0)
    assert amounts.shape[1] == len(PROTOCOL)
    assert (np.count_nonzero(amounts > 1e-9, axis=1) <= 1).all()  # never two steps at once
    assert np.isclose(amounts.max(0), 1.0).all()  # each held at full
    assert 20.0 <= len(amounts) / 30.0 <= 45.0  # the 20-40 s, about
    targets = target_matrix()
    assert targets.shape == (len(ARKIT_NAMES), len(PROTOCOL))
    k = [s.name for s in PROTOCOL].index("jaw_open")
    assert targets[ARKIT_NAMES.index("jawOpen"), k] == 1.0 and targets[:, k].sum() == 1.0
    # every goal curve of the issue is shown by some step
    for name in ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp", "browDownLeft", "browDownRight",
                 "mouthSmileLeft", "mouthSmileRight"):
        assert targets[ARKIT_NAMES.index(name)].max() == 1.0, name


def test_align_keeps_the_order_and_skips_a_missing_step():
    # four runs for five steps; run 2 looks like step 3 (step 2 left out by the actor)
    sim = np.full((4, 5), -0.2)
    for run, step in ((0, 0), (1, 1), (2, 3), (3, 4)):
        sim[run, step] = 0.9
    assert align(sim) == [(0, 0), (1, 1), (2, 3), (3, 4)]
    # with no reading at all (every similarity 0), the order alone matches run k to step k
    assert align(np.zeros((3, 3))) == [(0, 0), (1, 1), (2, 2)]


def test_find_runs_one_per_expression_with_its_hold():
    fps = 30.0
    t = np.arange(300) / fps
    act = np.full(300, 1.0)
    for centre, peak in ((2.0, 20.0), (4.0, 6.0), (6.0, 40.0)):
        act += peak * np.exp(-0.5 * ((t - centre) / 0.3) ** 2)
    runs = find_runs(act, fps, np.ones(300, bool))
    assert len(runs) == 3
    for run, centre in zip(runs, (2.0, 4.0, 6.0)):
        assert isinstance(run, Run) and run.start <= run.hold_start < run.hold_stop <= run.stop
        assert abs((run.hold_start + run.hold_stop) / 2 / fps - centre) < 0.1
    # a face lost over a run's frames takes the run away
    valid = np.ones(300, bool)
    valid[150:270] = False
    assert len(find_runs(act, fps, valid)) == 2


def test_step_weights_recover_a_bounded_mix():
    rng = np.random.default_rng(0)
    basis = rng.normal(size=(6, 200))
    true = np.clip(rng.uniform(-0.5, 1.2, (50, 6)), 0.0, MAX_WEIGHT)
    w = step_weights(true @ basis, basis)
    assert w.min() >= 0.0 and w.max() <= MAX_WEIGHT
    # the ridge shrinks each weight by ~2 %: recovered within that
    assert np.abs(w - true).max() < 0.05
    # a negative mix reads 0, never below
    assert step_weights(-basis[:1], basis)[0, 0] == 0.0


def _calibration() -> ActorCalibration:
    rng = np.random.default_rng(1)
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return ActorCalibration(
        source="rom.mp4", fps=30.0,
        steps=[StepFit("brows_up", True, (10, 40), (15, 35), 0.9, {"browInnerUp": 0.4}, {"browInnerUp": 0.98}),
               StepFit("frown", False)],
        rest_face=f32(rng.normal(size=(478, 3))), rest_landmarks=f32(rng.normal(size=(478, 3))),
        rest_scores=f32(rng.uniform(size=52)), score_names=["_neutral", *ARKIT_NAMES[:51]],
        pose_model=f32(rng.normal(size=(13, 30))), basis=f32(rng.normal(size=(1, 30))),
        basis_steps=["brows_up"], noise=f32([0.1]),
        curves={"browInnerUp": {"source": "expressions", "gain": 1.1, "offset": -0.02, "steps": ["brows_up"]},
                "browDownLeft": {"source": "expressions", "gain": 1.0, "offset": 0.0, "steps": [],
                                 "explained_by": {"brows_up": 0.2}}},
        warnings=["calibration: the take shows no 'frown'"])


def test_actor_json_round_trips_and_reads_edits(tmp_path):
    cal = _calibration()
    path = tmp_path / "actor.json"
    cal.save(path)
    back = ActorCalibration.load(path)
    assert back.to_json() == cal.to_json()
    data = json.loads(path.read_text())
    data["curves"]["browInnerUp"]["gain"] = 0.7  # what a user edits
    path.write_text(json.dumps(data))
    assert ActorCalibration.load(path).curves["browInnerUp"]["gain"] == 0.7


def test_explained_away_takes_off_what_other_steps_raise():
    cal = _calibration()  # browDownLeft: 0.2 of brows_up's weight is not a frown
    names = cal.score_names
    curves = np.zeros((3, len(names)), np.float32)
    curves[:, names.index("browDownLeft")] = [0.5, 0.1, 0.9]
    curves[:, names.index("browInnerUp")] = 0.4
    out = explained_away(curves.copy(), cal, names, np.array([[1.0], [1.0], [0.0]]))
    np.testing.assert_allclose(out[:, names.index("browDownLeft")], [0.3, 0.0, 0.9], atol=1e-6)
    inner = names.index("browInnerUp")
    np.testing.assert_array_equal(out[:, inner], curves[:, inner])  # no explained_by: as it was
    assert explained_away(curves.copy(), cal, names, np.zeros((3, 0))).tolist() == curves.tolist()  # no weights


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("format"), "not an actor calibration"),
    (lambda d: d["curves"]["browInnerUp"].update(steps=["smile"]), "names steps the calibration lacks"),
    (lambda d: d["curves"]["browDownLeft"].update(explained_by={"look_up": 0.5}), "names steps the calibration lacks"),
    (lambda d: d["curves"]["browInnerUp"].update(source="guess"), "source must be"),
    (lambda d: d["rest"].update(landmarks=[[0, 0, 0]]), "not 478 landmarks"),
    (lambda d: d.pop("basis"), "damaged"),
])
def test_actor_json_damage_is_one_line(tmp_path, edit, message):
    data = _calibration().to_json()
    edit(data)
    path = tmp_path / "actor.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CaptureError, match=message):
        ActorCalibration.load(path)
    path.write_text("{not json")
    with pytest.raises(CaptureError, match="not JSON"):
        ActorCalibration.load(path)


# ---- against the truth: a synthetic actor's performance, calibrated by its own ROM take ----
@pytest.mark.slow
def test_a_calibration_reads_the_brows_mediapipe_misses(actor_json, tmp_path):
    """ict-a's performance (seed 0) read with its actor.json: the frown MediaPipe scores as
    nothing follows the truth, and browInnerUp's error falls to a fraction of MediaPipe's."""
    from capture2face.calibration.attach import attach
    from capture2face.character.load import load_character
    from capture2face.eval.synthetic import arkit_columns
    from capture2face.maths.stats import pearson
    from capture2face.retarget.arkit import arkit_curves
    from capture2face.synth import SynthOptions, synthesize
    from capture2face.tracking import TrackOptions, track_clip
    from tests.helpers import shared_character

    actor = load_character(shared_character("ict-a.glb"))
    clip = synthesize(tmp_path / "perf.mp4", SynthOptions(frames=300, size=256, seed=0), progress=False, actor=actor)
    track = track_clip(clip.video_path, TrackOptions(), progress=False)
    before = arkit_curves(track)
    after = arkit_curves(attach(track, ActorCalibration.load(actor_json)))
    names, truth = list(track.blendshape_names), clip.truth
    columns = arkit_columns(truth.blend_names)
    figures = {}
    for name in ("browDownLeft", "browDownRight", "browInnerUp", "eyeBlinkLeft", "mouthSmileLeft"):
        c, t = names.index(name), truth.blend_weights[:, columns[name]].astype(np.float64)
        figures[name] = {"r": pearson(after[:, c], t), "r_before": pearson(before[:, c], t),
                         "mae": float(np.abs(after[:, c] - t).mean()),
                         "mediapipe_mae": float(np.abs(track.blendshapes[:, c] - t).mean())}
    for side in ("Left", "Right"):
        f = figures["browDown" + side]
        assert f["r"] > f["r_before"] + 0.2 and f["r"] > 0.6 and f["mae"] < f["mediapipe_mae"], figures
    assert figures["browInnerUp"]["mae"] < 0.5 * figures["browInnerUp"]["mediapipe_mae"], figures
    for name in ("eyeBlinkLeft", "mouthSmileLeft"):  # what the tracker reads well stays read well
        assert figures[name]["r"] > 0.85, figures

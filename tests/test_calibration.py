"""The calibration core: the protocol, finding its steps, the actor's expression mix, actor.json."""

from __future__ import annotations

import json

import numpy as np
import pytest

from capture2face.calibration import PROTOCOL, ActorCalibration, StepFit
from capture2face.calibration.learn import explained_away, tracker_adjusted
from capture2face.calibration.protocol import step_amounts, target_matrix
from capture2face.calibration.segment import Run, align, find_runs, own_hold
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


def test_own_hold_is_the_longest_plateau_of_the_steps_own_groups():
    own = np.full(100, 1.0)
    own[10:14] = 9.0  # the previous step's return, brief (the run began on it)
    own[30:55] = 8.0  # the step's own hold
    own[60:70] = 3.0
    run = Run(5, 80, 10, 14)  # held where the largest group peaked
    assert own_hold(run, own) == Run(5, 80, 30, 55)
    assert own_hold(run, np.zeros(100)) == run  # its groups never move: as found


def test_the_pose_model_is_fitted_on_the_holds_too(monkeypatch):
    """Idle frames that span little of the head's motion leave the pose model undetermined;
    the holds' frames (each with its own constant, the step's row) determine it."""
    from capture2face.calibration import learn
    from capture2face.calibration.learn import _joint_pose

    monkeypatch.setattr(learn, "POSE_RIDGE", 0.0)
    rng = np.random.default_rng(2)
    frames, n_terms = 400, 4
    terms = np.concatenate([rng.normal(size=(frames, n_terms - 1)), np.ones((frames, 1))], 1)
    terms[:100, :-1] *= 0.01  # the idle frames: the head almost still
    true = rng.normal(size=(n_terms, 6))
    holds = [Run(100 + 60 * j, 160 + 60 * j, 110 + 60 * j, 150 + 60 * j) for j in range(5)]
    rows = rng.normal(size=(5, 6))
    raw = terms @ true + 0.01 * rng.normal(size=(frames, 6))
    for h, row in zip(holds, rows):
        raw[h.hold_start:h.hold_stop] += row
    model = _joint_pose(raw, terms, np.arange(100), holds)
    np.testing.assert_allclose(model, true, atol=0.02)
    # With the ridge, each term is held back by its spread (1 / (1 + ridge) of its slope on
    # these well-spanned terms); a term the frames do not span at all reads no effect.
    monkeypatch.setattr(learn, "POSE_RIDGE", 0.1)
    np.testing.assert_allclose(_joint_pose(raw, terms, np.arange(100), holds)[:-1], true[:-1] / 1.1, atol=0.05)
    terms[:, 0] = 0.5
    assert np.abs(_joint_pose(raw, terms, np.arange(100), holds)[0]).max() < 1e-6


def test_the_brows_raise_takes_its_highest_idle_weight_as_its_floor():
    """A clip's rest in another light reads as a little raise: the raise's floor is its
    highest weight on the take's idle frames, the others' their 90th percentile."""
    from capture2face.calibration.learn import _noise_floor

    idle = np.tile(np.linspace(0.0, 1.0, 101)[:, None], (1, 2))
    np.testing.assert_allclose(_noise_floor(idle, ["brows_up", "frown"]), [1.0, 0.9], atol=1e-6)


def test_a_faint_step_the_tracker_does_not_read_is_not_learned():
    from capture2face.calibration.features import LANDMARKS, curve_mask
    from capture2face.calibration.learn import _learn_step

    names = ["_neutral", *ARKIT_NAMES]
    cols = np.arange(1, len(names))
    step = PROTOCOL[[s.name for s in PROTOCOL].index("frown")]
    targets = target_matrix(names, PROTOCOL)
    k = PROTOCOL.index(step)
    feats = np.zeros((100, 3 * len(LANDMARKS) + len(cols)))
    feats[40:60] = 0.3 * curve_mask(step.targets, names, cols)  # the brows move, well above the noise
    feats[:20] += 0.001
    reading = np.zeros((100, len(names)))
    run = Run(35, 65, 40, 60)
    fit, row, warning = _learn_step(k, step, run, True, feats, np.arange(20), reading, targets, names, cols)
    assert not fit.found and row is None and "too faintly to learn" in warning
    reading[40:60, names.index("browDownLeft")] = reading[40:60, names.index("browDownRight")] = 0.4
    fit, row, warning = _learn_step(k, step, run, True, feats, np.arange(20), reading, targets, names, cols)
    assert fit.found and row is not None and "shows faintly" in warning  # read as itself: learned, named
    fit, row, warning = _learn_step(k, step, run, False, feats, np.arange(20), np.zeros_like(reading), targets,
                                    names, cols)
    assert fit.found and row is not None and warning == ""  # a clear run the tracker cannot read: learned


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
                                 "explained_by": {"brows_up": 0.2}},
                "jawOpen": {"source": "tracker", "gain": 1.0, "offset": 0.0, "steps": [],
                            "score": {"share": 0.5, "gain": 1.2, "offset": -0.1}}},
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


def test_several_takes_calibrate_together_and_round_trip(tmp_path):
    """Each take's calibration is kept whole (its own gains, steps and warnings) and reads
    back from actor.json; a calibration of several takes joined again keeps them all."""
    first, second = _calibration(), _calibration()
    second.source, second.curves["browInnerUp"]["gain"] = "rom2.mp4", 0.5
    both = ActorCalibration.together([first, second])
    assert [t.source for t in both.takes] == ["rom.mp4", "rom2.mp4"] and not first.more_takes
    path = tmp_path / "actor.json"
    both.save(path)
    back = ActorCalibration.load(path)
    assert back.to_json() == both.to_json()
    assert back.more_takes[0].curves["browInnerUp"]["gain"] == 0.5 and back.curves["browInnerUp"]["gain"] == 1.1
    assert json.loads(path.read_text())["more_takes"][0]["source"] == "rom2.mp4"  # plain JSON
    assert len(ActorCalibration.together([both, _calibration()]).takes) == 3
    other = _calibration()
    other.score_names = other.score_names[:-1] + ["tongueOut"]
    with pytest.raises(CaptureError, match="same tracker"):
        ActorCalibration.together([first, other])
    data = both.to_json()
    data["more_takes"][0]["curves"]["browInnerUp"]["source"] = "guess"
    path.write_text(json.dumps(data))
    with pytest.raises(CaptureError, match=r"take 2\): curve browInnerUp's source"):
        ActorCalibration.load(path)


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


def test_tracker_curve_averaged_with_its_score_where_given():
    cal = _calibration()  # jawOpen: the geometry half, the score on its line (1.2 s - 0.1) half
    names = cal.score_names
    jaw = names.index("jawOpen")
    curves = np.zeros((3, len(names)), np.float32)
    curves[:, jaw] = [0.2, 0.5, 1.0]
    out = tracker_adjusted(curves.copy(), cal, names, {"jawOpen": np.array([0.0, 0.25, 0.5])})
    np.testing.assert_allclose(out[:, jaw], [0.1 - 0.05, 0.25 + 0.1, 0.5 + 0.25], atol=1e-6)
    top = tracker_adjusted(curves.copy(), cal, names, {"jawOpen": np.ones(3)})[:, jaw]
    assert top.max() == 1.0  # clipped to [0, 1]
    # no score given (the curve alone, as before the share): its gain and offset only
    np.testing.assert_allclose(tracker_adjusted(curves.copy(), cal, names)[:, jaw], curves[:, jaw], atol=1e-6)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("format"), "not an actor calibration"),
    (lambda d: d["curves"]["browInnerUp"].update(steps=["smile"]), "names steps the calibration lacks"),
    (lambda d: d["curves"]["browDownLeft"].update(explained_by={"look_up": 0.5}), "names steps the calibration lacks"),
    (lambda d: d["curves"]["browInnerUp"].update(source="guess"), "source must be"),
    (lambda d: d["curves"]["jawOpen"]["score"].pop("share"), "damaged"),
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
    # browInnerUp, the brows' height read against the take's neutral instead of the clip's
    # calmest brows (a frown on this performance), follows the truth better than before
    assert ActorCalibration.load(actor_json).curves["browInnerUp"]["source"] == "geometry"
    assert figures["browInnerUp"]["r"] > max(0.9, figures["browInnerUp"]["r_before"] + 0.05), figures
    for name in ("eyeBlinkLeft", "mouthSmileLeft"):  # what the tracker reads well stays read well
        assert figures[name]["r"] > 0.85, figures
    # Two takes calibrating together: the curves are the mean of each take's reading (the
    # second take here is the first with two curves edited).
    first = ActorCalibration.load(actor_json)
    second = ActorCalibration.load(actor_json)
    second.curves["browInnerUp"]["gain"] *= 0.5
    second.curves["browDownLeft"]["offset"] += 0.1
    alone = arkit_curves(attach(track, second))
    both = arkit_curves(attach(track, ActorCalibration.together([first, second])))
    np.testing.assert_allclose(both, (after + alone) / 2, atol=1e-6)
    inner = names.index("browInnerUp")
    assert np.abs(both[:, inner] - after[:, inner]).max() > 0.05  # the edit shows, halved

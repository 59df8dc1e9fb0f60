"""Learning an actor's calibration from a tracked ROM take (:func:`calibrate`) and applying
it to a clip of the same actor (:func:`calibrated_curves`).

The actor's basis: for each protocol step found in the take, the change of the frame
features (:mod:`~capture2face.calibration.features`) from the actor's rest at the step's
hold: how *this* face, as *this* tracker reads it, shows the expression. A frame of any
clip is then the bounded least-squares mix of those steps
(:func:`~capture2face.calibration.solve.step_weights`), and each ARKit curve the mix of
the steps' weights of it: a frown MediaPipe scores as nothing still moves this actor's
brows somewhere. A curve the tracker reads well on the take keeps the tracker's reading
(with the take's range where it is compressed).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import nnls
from threadpoolctl import threadpool_limits

from capture2face.calibration.features import (
    curve_groups,
    curve_mask,
    curve_region,
    frame_features,
    group_motion,
    pose_terms,
)
from capture2face.calibration.model import ActorCalibration, StepFit
from capture2face.calibration.protocol import PROTOCOL, STEP_NAMES, Step, target_matrix
from capture2face.calibration.segment import MATCH_WARN, activity, align, find_runs, idle_frames, own_hold, weak_runs
from capture2face.calibration.solve import step_weights
from capture2face.maths.stats import pearson
from capture2face.tracking.rest import ActorRest, actor_rest, aligned_rest, clip_rest

MIN_NEUTRAL_FRAMES = 5
# A step whose hold moves its regions' features less than this many times their RMS on the
# take's idle frames is not learned: its basis row is the take's noise, which the mix then
# uses to explain whatever its other rows miss (ICT-a's faint eyes_wide took weights of 1-1.7
# in frowns and jaw drops).
MIN_ROW_NOISE = 2.0
OTHER_READING = 0.3  # a step's hold the tracker reads as another curve this high is named
_CHUNK = 4096
GAIN_BOUNDS, OFFSET_BOUNDS = (0.5, 3.0), (-0.3, 0.3)
# A curve the tracker's own reading follows on the take this well (Pearson r over the holds
# and the idle frames) keeps that reading, with the take's gain and offset ("tracker"); the
# others come from the actor's expressions ("expressions"). On a synthetic ICT actor the
# expressions' blink, fitted on 0.8 s holds, missed the performance's 0.25 s blinks (r 0.65
# where the tracker's reads 0.93), while the brows the tracker barely reads came out right.
TRACKER_R, TRACKER_GAIN_MAX, TRACKER_OFFSET_MAX = 0.7, 2.0, 0.1
# A tracker's curve whose take gain falls in this range keeps its reading unchanged: the
# smiles' gains of 1.06-1.13 on ICT takes raised their error past MediaPipe's raw score.
TRACKER_KEEP = (0.8, 1.25)
# A tracker's curve that is the face's geometry (``retarget.arkit.GEOMETRIC``) listed here is
# averaged, at this share, with the tracker's own score on the take's line from it: the
# lip gap reads a funnel, a raised upper lip or a lowered lower lip as the jaw and lips held
# closed over an open jaw as none (ICT's funnel hold parts the lips and drops the chin 0.65
# as far as its jaw hold), while MediaPipe's jawOpen score misses less of those (0.01-0.03
# at the upper lip's hold) and errs elsewhere. jawOpen r 0.81-0.87 -> 0.84-0.90 across takes.
SCORE_SHARE = {"jawOpen": 0.5}
# Curves read from the face's geometry (``retarget.arkit.GEOMETRIC``) against the take's rest
# laid onto the clip (source "geometry"): the brows' height. A clip's own rest is where
# MediaPipe reads the brows calmest, which on ICT performances was a frown (browDown
# 0.58-0.99 at the picked frame); the take's opening neutral is a neutral. Against it the
# brows' height follows browInnerUp better than the expressions' mix on every performance
# and take measured ("Across takes", round seven).
TAKE_REST_GEOMETRY = ("browInnerUp",)
# The regions whose curves learn what other regions' steps raise (_fit_explained), and the
# least share kept.
EXPLAIN_REGIONS, EXPLAIN_MIN = ("brow", "eye"), 0.01
POSE_ROUNDS = 4  # fits of the pose model, each on the idle frames of the one before
# Each step's noise floor: this percentile of its weight over the take's idle frames; the
# steps named after it take the highest. A clip's rest, in another light and head motion than
# the take's, reads as a little of the brows' raise (browInnerUp sat 0.08-0.23 above the
# truth at ICT performances' rest); the frown's floor raised as well cost the frown (r 0.87 ->
# 0.84 on ict-a seed 0).
NOISE_PERCENTILE, NOISE_FULL_STEPS = 90.0, ("brows_up",)
# The ridge on each pose term of the fit on the holds (relative to the term's spread over the
# fitted frames and their count): the terms a take spans little (the rotation's squares and
# products) otherwise extrapolate differently from take to take (browDown's lowest r over
# three takes of ict-a seed 1 0.68 -> 0.76 with it).
POSE_RIDGE = 0.1


def _score_columns(names: list[str]) -> np.ndarray:
    return np.array([i for i, n in enumerate(names) if n != "_neutral"])


def _reading(scores: np.ndarray, rest_scores: np.ndarray, names: list[str]) -> np.ndarray:
    """(F, S) the tracker's scores calibrated to rest, as the uncalibrated curves read them."""
    rest = np.clip(rest_scores, 0.0, 0.99)
    return np.clip((np.nan_to_num(scores) - rest) / (1.0 - rest), 0.0, 1.0)


@threadpool_limits.wrap(limits=1, user_api="blas")  # small matrices: BLAS threads only wait on each other
def calibrate(track, steps: tuple[Step, ...] = PROTOCOL, base_curves: np.ndarray | None = None) -> ActorCalibration:
    """Learn ``track`` (a tracked ROM take, :class:`~capture2face.tracking.track.Track`) as
    the protocol ``steps`` in order. A step the take does not show, or shows unlike itself,
    is named in ``warnings``; a take of the neutral alone learns the rest and no curve.

    Args:
        base_curves: (F, S) the take's uncalibrated curves (``retarget.arkit.arkit_curves``),
            for each step's before/after in the report; None: the scores calibrated to rest.
    """
    names = list(track.blendshape_names)
    cols = _score_columns(names)
    fps = float(track.fps) if track.fps and np.isfinite(track.fps) else 30.0
    valid = np.asarray(track.presence, bool)
    terms = pose_terms(track.head_pose)
    # Twice: first from the take's calmest frames per region (the brows' may be the frown's),
    # then from its opening neutral, found by the first pass; what is learned is relative to
    # the second pass's rest, the one the calibration keeps.
    rest = actor_rest(track)
    for last in (False, True):
        raw = frame_features(track.landmarks_head, track.blendshapes, rest.landmarks, rest.scores, cols)
        pose_model, idle = _pose_model(raw, terms, valid)
        feats = raw - terms @ pose_model
        act = activity(group_motion(feats), idle, fps)
        runs = find_runs(act, fps, valid)
        if not last:
            rest = _neutral_rest(track, idle, runs)
    rest_frames = idle

    reading = _reading(np.asarray(track.blendshapes, np.float64), rest.scores, names)
    targets = target_matrix(names, steps)  # (S, K)
    found, weak = _find_steps(reading, targets, act, runs, fps, valid)
    found, weak = (_own_holds(d, steps, group_motion(feats), idle, fps) for d in (found, weak))
    # The head's effect again, now on the holds as well as the idle frames (each hold's own
    # constant its step's row): the idle frames alone span little of the take's head motion,
    # so their fit extrapolated differently from take to take.
    pose_model = _joint_pose(raw, terms, idle, [found.get(k) or weak[k] for k in sorted({*found, *weak})])
    feats = raw - terms @ pose_model

    fits, rows, row_steps, warnings = [], [], [], []
    for k, step in enumerate(steps):
        fit, row, warning = _learn_step(k, step, found.get(k) or weak.get(k), k in weak, feats, idle, reading,
                                        targets, names, cols)
        fits.append(fit)
        warnings += [warning] if warning else []
        if row is not None:
            rows.append(row)
            row_steps.append(step.name)
    basis = np.asarray(rows, np.float32).reshape(len(rows), feats.shape[1])
    calibration = ActorCalibration(
        source=str(track.source), fps=fps, steps=fits, rest_face=rest.face, rest_landmarks=rest.landmarks,
        rest_scores=rest.scores, score_names=names, pose_model=pose_model.astype(np.float32),
        basis=basis, basis_steps=row_steps, noise=np.zeros(len(row_steps), np.float32),
        curves=_curves(names, steps, row_steps), warnings=warnings)
    if len(basis) and len(rest_frames):
        calibration.noise = _noise_floor(step_weights(feats[rest_frames], basis), row_steps)
    base = base_curves if base_curves is not None else reading
    weights = _weights(feats, calibration) if len(basis) else np.zeros((len(feats), 0))  # the take's mix, once
    _fit_gains(calibration, weights, base, fits, rest_frames, steps, reading)
    scores = score_readings(calibration, names, reading)
    _fit_explained(calibration, track, weights, base, fits, steps, rest_frames, scores)
    _report_steps(calibration, track, base, weights, scores)
    return calibration


def _learn_step(k: int, step: Step, run, faint: bool, feats: np.ndarray, idle: np.ndarray, reading: np.ndarray,
                targets: np.ndarray, names: list[str], cols: np.ndarray) -> tuple[StepFit, np.ndarray | None, str]:
    """(fit, its basis row or None, a warning or "") of protocol step ``k`` found as ``run``
    (None: not found; ``faint``: found by its place in the order only): the mean of
    ``feats`` (F, D) over its hold, on its curves' regions."""
    if run is None:
        return StepFit(step.name, False), None, (f"calibration: the take shows no '{step.name}' "
                                                 f"({step.instruction.lower()}): its curves keep the tracker's reading")
    frames = f"frames {run.start}-{run.stop - 1}"
    mask = curve_mask(step.targets, names, cols)
    row = feats[run.hold_start:run.hold_stop].mean(0) * mask
    if np.linalg.norm(row) < MIN_ROW_NOISE * np.sqrt(((feats[idle] * mask) ** 2).sum(1).mean()):
        return StepFit(step.name, False), None, (f"calibration: '{step.name}' moves the face too little to learn "
                                                 f"({frames}, within twice the take's noise): its curves keep the "
                                                 "tracker's reading")
    v = reading[run.hold_start:run.hold_stop].mean(0)
    match = float(targets[:, k] @ v / (np.linalg.norm(targets[:, k]) * max(np.linalg.norm(v), 1e-9)))
    if faint and match < MATCH_WARN:
        # Faint and unread: on synthetic takes such holds were mostly another step's return
        # (a frown the light hid, found on the brows' way down from the raise: browDown r -0.37).
        return StepFit(step.name, False), None, (f"calibration: '{step.name}' shows too faintly to learn ({frames}, "
                                                 "found by its place in the order, and the tracker does not read "
                                                 "it as itself): its curves keep the tracker's reading")
    warning = ""
    if faint:
        warning = (f"calibration: '{step.name}' shows faintly ({frames}, found by its place in the order); check "
                   "the take, or edit actor.json")
    elif match < MATCH_WARN and v.max() >= OTHER_READING and targets[int(np.argmax(v)), k] == 0.0:
        # Read as another expression (not merely unread: MediaPipe scores no cheek puff).
        warning = (f"calibration: '{step.name}' ({frames}) reads as {names[int(np.argmax(v))]} {v.max():.2f}; "
                   "check the take, or edit actor.json")
    fit = StepFit(step.name, True, (run.start, run.stop - 1), (run.hold_start, run.hold_stop - 1), round(match, 3))
    return fit, row, warning


def _find_steps(reading: np.ndarray, targets: np.ndarray, act: np.ndarray, runs: list, fps: float,
                valid: np.ndarray) -> tuple[dict, dict]:
    """(found, weak): step index -> its run, the runs laid onto the steps' order by the
    tracker's reading (F, S) of each against the steps' ``targets`` (S, K)
    (:func:`~capture2face.calibration.segment.align`), and the faint steps looked for where
    the order puts them (:func:`~capture2face.calibration.segment.weak_runs`)."""
    sim = np.zeros((len(runs), targets.shape[1]))
    for i, run in enumerate(runs):
        v = reading[run.hold_start:run.hold_stop].mean(0)
        sim[i] = (targets.T @ v) / (np.linalg.norm(targets, axis=0) * max(np.linalg.norm(v), 1e-9))
    pairs = {k: i for i, k in align(sim)} if len(runs) else {}
    found = {k: runs[i] for k, i in pairs.items()}
    return found, (weak_runs(act, found, targets.shape[1], fps, valid) if found else {})


def _own_holds(runs: dict, steps: tuple[Step, ...], motion: np.ndarray, idle: np.ndarray, fps: float) -> dict:
    """step index -> its run with the hold found on the step's own landmark groups
    (:func:`~capture2face.calibration.segment.own_hold`; ``motion`` (F, G) the take's group
    motion): a frown's run that merged into the lids' closing was held where the lids moved."""
    return {k: own_hold(r, activity(motion[:, curve_groups(steps[k].targets)], idle, fps)) for k, r in runs.items()}


def _neutral_rest(track, idle: np.ndarray, runs: list) -> ActorRest:
    """The take's rest: each region's calmest frames (:func:`~capture2face.tracking.rest.clip_rest`)
    among its idle frames before the first step (the protocol opens on the neutral), or
    among all its idle frames when fewer than :data:`MIN_NEUTRAL_FRAMES` come first."""
    first = idle[idle < runs[0].start] if runs else idle
    candidates = np.zeros(track.n_frames, bool)
    candidates[first if len(first) >= MIN_NEUTRAL_FRAMES else idle] = True
    rest = clip_rest(track.landmarks_head, track.blendshapes, list(track.blendshape_names), track.head_pose,
                     track.times, candidates & np.asarray(track.presence, bool))
    return dataclasses.replace(rest, source=f"the neutral of {track.source}")


def _pose_model(raw: np.ndarray, terms: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, D) how the features of a still face follow the head's pose terms (F, P), fitted on
    the take's idle frames (found again from each fit's residuals), and those frames."""
    idle = np.flatnonzero(valid)
    model = np.zeros((terms.shape[1], raw.shape[1]))
    for _ in range(POSE_ROUNDS):
        model, *_ = np.linalg.lstsq(terms[idle], raw[idle], rcond=None)
        idle = idle_frames(group_motion(raw - terms @ model), valid)
    return model, idle


def _joint_pose(raw: np.ndarray, terms: np.ndarray, idle: np.ndarray, holds: list) -> np.ndarray:
    """(P, D) the pose model (:func:`_pose_model`) fitted on the take's ``idle`` frames and
    the ``holds`` of its steps (runs) together, each hold with a constant of its own (the
    step's change, fitted with it and dropped), each pose term (all but the last, the
    constant) held back by a ridge of :data:`POSE_RIDGE` on its spread over those frames."""
    frames = np.concatenate([idle] + [np.arange(h.hold_start, h.hold_stop) for h in holds])
    onehot = np.zeros((len(frames), len(holds)))
    at = len(idle)
    for j, h in enumerate(holds):
        onehot[at:at + h.hold_stop - h.hold_start, j] = 1.0
        at += h.hold_stop - h.hold_start
    t = terms[frames, :-1]
    mean, spread = t.mean(0), np.maximum(t.std(0), 1e-9)
    p = t.shape[1]
    # The ridge as extra rows: sqrt(ridge * N) times each scaled term's coefficient -> 0.
    x = np.concatenate([(t - mean) / spread, np.ones((len(frames), 1)), onehot], 1)
    x = np.concatenate([x, np.sqrt(POSE_RIDGE * len(frames)) * np.eye(p, x.shape[1])])
    y = np.concatenate([raw[frames], np.zeros((p, raw.shape[1]))])
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    slope = coef[:p] / spread[:, None]
    return np.concatenate([slope, coef[p:p + 1] - mean @ slope])


def _noise_floor(idle_weights: np.ndarray, row_steps: list[str]) -> np.ndarray:
    """(K,) float32 each basis row's noise floor from its (F, K) weights over the take's idle
    frames (:data:`NOISE_PERCENTILE`, the highest for :data:`NOISE_FULL_STEPS`)."""
    q = [100.0 if s in NOISE_FULL_STEPS else NOISE_PERCENTILE for s in row_steps]
    return np.array([np.percentile(idle_weights[:, k], q[k]) for k in range(len(q))], np.float32)


def _curves(names: list[str], steps: tuple[Step, ...], found: list[str]) -> dict[str, dict]:
    """ARKit name -> {"source", "gain": 1, "offset": 0, "steps": the found steps that show it}."""
    out = {}
    for name in names:
        shown = [s.name for s in steps if s.name in found and s.targets.get(name, 0.0) > 0.0]
        if shown:
            out[name] = {"source": "expressions", "gain": 1.0, "offset": 0.0, "steps": shown, "explained_by": {}}
    return out


def _weights(feats: np.ndarray, calibration: ActorCalibration) -> np.ndarray:
    """(F, K) each step's weight in (F, D) ``feats``, its noise taken off (a weight at the
    idle frames' level reads 0, a hold's still 1)."""
    w = step_weights(feats, calibration.basis)
    noise = np.clip(np.asarray(calibration.noise, np.float64), 0.0, 0.9)
    return np.clip((w - noise) / (1.0 - noise), 0.0, None)


def _mix(calibration: ActorCalibration, weights: np.ndarray) -> np.ndarray:
    """(F, S) each score column's curve from (F, K) step weights, before gain and offset."""
    steps = {s.name: s for s in PROTOCOL}
    return weights @ target_matrix(calibration.score_names, tuple(steps[n] for n in calibration.basis_steps)).T


def _fit_gains(calibration: ActorCalibration, weights: np.ndarray, base: np.ndarray, fits: list[StepFit],
               rest_frames: np.ndarray, steps: tuple[Step, ...], reading: np.ndarray) -> None:
    """Each curve's source (:data:`TAKE_REST_GEOMETRY`, :data:`TRACKER_R`), gain and offset:
    its reading (the tracker's ``base`` (F, S) curves, or the expressions' mix) over the
    take's holds (each step's target) and idle frames (0) fitted by least squares, within
    :data:`GAIN_BOUNDS` and :data:`OFFSET_BOUNDS`; for a tracker's curve in
    :data:`SCORE_SHARE`, its ``score``: the same line from the take's scores calibrated to
    rest (``reading`` (F, S))."""
    if not len(calibration.basis):
        return
    found = [(f, s) for f, s in zip(fits, steps) if f.found]
    frames = np.concatenate([np.arange(f.hold[0], f.hold[1] + 1) for f, _ in found] + [rest_frames])
    lengths = [f.hold[1] - f.hold[0] + 1 for f, _ in found]
    held = np.repeat(target_matrix(calibration.score_names, tuple(s for _, s in found)).T, lengths, 0)
    goal = np.concatenate([held, np.zeros((len(rest_frames), held.shape[1]))])  # (N, S)
    shows = goal > 0.0  # the frames of the holds of the steps that show each curve, and idle ones
    shows[len(held):] = True
    col = {n: i for i, n in enumerate(calibration.score_names)}
    mix = _mix(calibration, weights[frames])
    for name, c in calibration.curves.items():
        if name in TAKE_REST_GEOMETRY:  # the uncalibrated curve's geometry from the take's rest
            c["source"], c["gain"], c["offset"] = "geometry", 1.0, 0.0
            continue
        use = shows[:, col[name]]
        y = goal[use, col[name]]
        tracker = base[frames[use], col[name]].astype(np.float64)
        gain, offset = _line(tracker, y)
        # The tracker's own curve where it follows the holds and reaches their range
        # without being blown up (a browDown MediaPipe scores 0.01 at a frown follows the
        # frown, but is the tracker's noise times 30) or moved (a curve that reads well
        # above 0 at the take's rest reads the clip's rest wrong, as browInnerUp on a take
        # whose calmest brows are its frown's).
        if pearson(tracker, y) >= TRACKER_R and gain <= TRACKER_GAIN_MAX and abs(offset) <= TRACKER_OFFSET_MAX:
            c["source"] = "tracker"
            if TRACKER_KEEP[0] <= gain <= TRACKER_KEEP[1]:  # within the take's noise: left as read
                gain, offset = 1.0, 0.0
        else:
            c["source"] = "expressions"
            gain, offset = _line(mix[use, col[name]], y)
        c["gain"] = round(float(np.clip(gain, *GAIN_BOUNDS)), 4)
        c["offset"] = round(float(np.clip(offset, *OFFSET_BOUNDS)), 4)
        if c["source"] == "tracker" and name in SCORE_SHARE:
            gain, offset = _line(reading[frames[use], col[name]], y)
            c["score"] = {"share": SCORE_SHARE[name], "gain": round(float(np.clip(gain, *GAIN_BOUNDS)), 4),
                          "offset": round(float(np.clip(offset, *OFFSET_BOUNDS)), 4)}


def _fit_explained(calibration: ActorCalibration, track, weights: np.ndarray, base: np.ndarray,
                   fits: list[StepFit], steps: tuple[Step, ...], rest_frames: np.ndarray,
                   scores: dict[str, np.ndarray]) -> None:
    """Each brow and eye curve's ``explained_by``: how much of it, as calibrated, the take's
    steps of other regions raise (non-negative least squares of the curve over the take's
    holds and idle frames on its own target and those steps' weights). On ICT takes looking
    up reads as a frown and a smile as a blink; those steps' weights come from other
    regions' landmarks, so a clip's frown or blink does not raise them."""
    if not len(calibration.basis):
        return
    names = calibration.score_names
    found = [(f, s) for f, s in zip(fits, steps) if f.found]
    goal = np.zeros((track.n_frames, len(names)))
    use, moving = np.zeros(track.n_frames, bool), np.zeros(track.n_frames, bool)
    targets = target_matrix(names, tuple(s for _, s in found))  # (S, K)
    for k, (f, _) in enumerate(found):
        goal[f.hold[0]:f.hold[1] + 1] = targets[:, k]
        use[f.hold[0]:f.hold[1] + 1] = True
        moving[f.frames[0]:f.frames[1] + 1] = True
    use[rest_frames[~moving[rest_frames]]] = True
    curves = tracker_adjusted(calibrated_curves(track, calibration, base, weights=weights), calibration, names, scores)
    weights = weights[use]
    by_name = {s.name: s for s in PROTOCOL}
    col = {n: i for i, n in enumerate(names)}
    for name, c in calibration.curves.items():
        region = curve_region(name)
        if region not in EXPLAIN_REGIONS or c["source"] == "geometry":
            continue
        others = [k for k, st in enumerate(calibration.basis_steps)
                  if all(curve_region(t) != region for t in by_name[st].targets)]
        coef, _ = nnls(np.concatenate([goal[use, col[name], None], weights[:, others]], 1), curves[use, col[name]])
        c["explained_by"] = {calibration.basis_steps[k]: round(float(b), 4)
                             for k, b in zip(others, coef[1:]) if b >= EXPLAIN_MIN}


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(gain, offset) of the least-squares line from (N,) ``x`` to ``y``."""
    (gain, offset), *_ = np.linalg.lstsq(np.stack([x, np.ones_like(x)], 1), y, rcond=None)
    return float(gain), float(offset)


def _report_steps(calibration: ActorCalibration, track, before: np.ndarray, weights: np.ndarray,
                  scores: dict[str, np.ndarray]) -> None:
    """Each found step's before/after: its curves' mean over the hold, uncalibrated and calibrated."""
    names = list(track.blendshape_names)
    after = explained_away(tracker_adjusted(calibrated_curves(track, calibration, before, weights=weights),
                                            calibration, names, scores), calibration, names, weights)
    col = {n: i for i, n in enumerate(calibration.score_names)}
    by_name = {s.name: s for s in PROTOCOL}
    for fit in calibration.steps:
        if not fit.found:
            continue
        span = slice(fit.hold[0], fit.hold[1] + 1)
        shown = [c for c in by_name[fit.name].targets if c in col]
        fit.before = {c: round(float(before[span, col[c]].mean()), 3) for c in shown}
        fit.after = {c: round(float(after[span, col[c]].mean()), 3) for c in shown}


def calibration_rest(calibration: ActorCalibration, track=None) -> ActorRest:
    """The calibration's rest as an :class:`ActorRest`; with ``track``, laid onto its head
    coordinates (:func:`~capture2face.tracking.rest.aligned_rest`)."""
    rest = ActorRest(face=calibration.rest_face, landmarks=calibration.rest_landmarks,
                     scores=calibration.rest_scores, frames={}, source=f"calibration {calibration.source}")
    return rest if track is None else aligned_rest(rest, track.landmarks_head, track.presence)


def _applies(track, calibration: ActorCalibration) -> bool:
    return bool(calibration.curves) and len(calibration.basis) > 0 and \
        list(track.blendshape_names) == calibration.score_names


def clip_weights(track, calibration: ActorCalibration, aligned: bool = True) -> np.ndarray:
    """(F, K) each found step's weight in each frame of ``track`` (K = 0 where the calibration
    does not apply), each frame read against the take's rest laid onto the clip's head
    coordinates (a clip's own rest is its calmest frames, which on a clip that frowns
    throughout is a frown), less the pose model's shift. ``aligned``: False when the track
    is the take itself."""
    if not _applies(track, calibration):
        return np.zeros((track.n_frames, 0))
    rest = calibration_rest(calibration, track if aligned else None)
    cols = _score_columns(calibration.score_names)
    out = np.empty((track.n_frames, len(calibration.basis)))
    for s in range(0, track.n_frames, _CHUNK):
        span = slice(s, min(s + _CHUNK, track.n_frames))
        feats = frame_features(track.landmarks_head, track.blendshapes, rest.landmarks, rest.scores, cols, span)
        feats -= pose_terms(np.asarray(track.head_pose[span])) @ calibration.pose_model
        out[span] = _weights(feats, calibration)
    return out


def calibrated_curves(track, calibration: ActorCalibration, base: np.ndarray, aligned: bool = True,
                      weights: np.ndarray | None = None) -> np.ndarray:
    """(F, S) float32: ``base`` (F, S) curves with each curve from the actor's expressions
    replaced by the calibration's mix of ``weights`` (:func:`clip_weights`, computed when
    None), before the caller's filter."""
    out = np.array(base, np.float32, copy=True)
    if not _applies(track, calibration):
        return out
    weights = clip_weights(track, calibration, aligned) if weights is None else weights
    col = {n: i for i, n in enumerate(calibration.score_names)}
    mix = _mix(calibration, weights)
    for name, c in calibration.curves.items():
        if c["source"] == "expressions":
            out[:, col[name]] = np.clip(c["gain"] * mix[:, col[name]] + c["offset"], 0.0, 1.0)
    return out


def explained_away(curves: np.ndarray, calibration: ActorCalibration, names: list[str],
                   weights: np.ndarray) -> np.ndarray:
    """(F, S) ``curves`` less what each curve's ``explained_by`` steps raise (their weights
    (F, K), :func:`clip_weights`, times the learned share), clipped to [0, 1] (in place)."""
    if weights.shape[1] != len(calibration.basis_steps):
        return curves
    col = {n: i for i, n in enumerate(names)}
    k = {n: i for i, n in enumerate(calibration.basis_steps)}
    for name, c in calibration.curves.items():
        shares = c.get("explained_by") or {}
        if shares and name in col:
            raised = sum(b * weights[:, k[s]] for s, b in shares.items())
            curves[:, col[name]] = np.clip(curves[:, col[name]] - raised, 0.0, 1.0)
    return curves


def tracker_adjusted(curves: np.ndarray, calibration: ActorCalibration, names: list[str],
                     scores: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """(F, S) ``curves`` with each curve the calibration keeps from the tracker scaled by its
    gain and offset, clipped to [0, 1] (in place); one with a ``score`` (:data:`SCORE_SHARE`)
    averaged at its share with ``scores[name]`` (F,) on the score's line (the tracker's score
    calibrated to rest, :func:`score_readings`), where given."""
    col = {n: i for i, n in enumerate(names)}
    for name, c in calibration.curves.items():
        if c.get("source") == "tracker" and name in col:
            curve = np.clip(c["gain"] * curves[:, col[name]] + c["offset"], 0.0, 1.0)
            mix = c.get("score")
            if mix and scores is not None and name in scores:
                read = mix["gain"] * np.asarray(scores[name], np.float64) + mix["offset"]
                curve = np.clip((1.0 - mix["share"]) * curve + mix["share"] * read, 0.0, 1.0)
            curves[:, col[name]] = curve
    return curves


def scored_curves(calibration: ActorCalibration, names: list[str]) -> list[str]:
    """The curves of ``names`` the calibration averages with the tracker's score (its
    ``score`` entry), in the calibration's order."""
    return [n for n, c in calibration.curves.items() if c.get("score") and n in names]


def score_readings(calibration: ActorCalibration, names: list[str], scores: np.ndarray) -> dict[str, np.ndarray]:
    """name -> (F,) column of ``scores`` (F, S), columns ``names``, for each of
    :func:`scored_curves`."""
    return {n: scores[:, names.index(n)] for n in scored_curves(calibration, names)}


__all__ = ["STEP_NAMES", "calibrate", "calibrated_curves", "calibration_rest", "clip_weights", "explained_away",
           "score_readings", "scored_curves", "tracker_adjusted"]

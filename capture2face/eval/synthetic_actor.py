"""Closed loop with any ARKit character as the actor (``eval synthetic --actor / --target``).

:mod:`capture2face.eval.synthetic` renders the default avatar and retargets it onto itself
(or a variant of the same topology), so it can compare bones, morphs and wrinkle influences
one for one. Here the actor is any character with ARKit-named morphs (an ICT-FaceKit head:
:func:`capture2face.synth.actor.random_arkit_performance`) or the default avatar, and the
target any character, of another topology too. What can be compared then:

* ``arkit_curves``: per ARKit name the actor has, this project's ARKit curves and
  MediaPipe's raw scores against the true weights
  (:func:`capture2face.eval.synthetic.arkit_curve_figures`);
* ``measures``: per fidelity measure (:data:`capture2face.measures.MEASURES`) the chain of
  ``eval synthetic``: the tracker's raw landmarks and the solved target against the truth,
  the truth being the actor's own landmark points deformed by its true weights (so the
  character's gain is the target's motion in its own inter-ocular units over the actor's
  in its own); each with ``moved`` (the truth's range reaches ``measures``'
  ``MIN_RANGE_IOD``, eyes ``MIN_RANGE_EYE``, what ``eval fidelity`` judges);
* ``blendweight_*``: the target's solved morph weights against the true ones, morphs
  paired by ARKit name (as ``eval synthetic``'s figures of the same names, over the
  ``blendweight_morphs`` shared names; ``_active_`` where the truth's std exceeds
  ``ACTIVE_STD``);
* the tracker's landmark error, the mouth opening's gain and r, the gaze errors, as in
  ``eval synthetic``;
* ``goals``: the issue's goals for realistic actors (:data:`ACTOR_GOALS`).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from capture2face.calibration.attach import attach
from capture2face.character.load import load_character
from capture2face.errors import CaptureError, NoFaceError
from capture2face.eval.synthetic import (
    active_morph_figures,
    arkit_columns,
    arkit_curve_figures,
    gaze_errors,
    landmark_figures,
    measure_chain,
    mouth_figures,
    rest_offsets,
    retarget_and_score,
)
from capture2face.measures import (
    EYE_MEASURES,
    MEASURES,
    MIN_RANGE_EYE,
    MIN_RANGE_IOD,
    character_measures,
    source_measures,
)
from capture2face.retarget import RetargetOptions
from capture2face.retarget.arkit import calibrate_take
from capture2face.retarget.gaze import eye_radius_iod
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig
from capture2face.synth import SynthOptions, actor_rig, synthesize
from capture2face.tracking import TrackOptions, track_clip
from capture2face.tracking.rest import with_frame_rest

# The curves the goals name: r >= 0.9 and an MAE below MediaPipe's where they move.
GOAL_CURVES = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "browInnerUp", "mouthSmileLeft", "mouthSmileRight",
               "browDownLeft", "browDownRight")
CURVE_R_GOAL = 0.9
MEASURE_R_GOAL, MEASURE_GAIN = 0.9, (0.8, 1.25)
ACTOR_GOALS: dict[str, str] = {
    "arkit_curves": f"r >= {CURVE_R_GOAL} and MAE below MediaPipe's on {', '.join(GOAL_CURVES)} where they move",
    "measures": f"character r >= {MEASURE_R_GOAL} and gain {MEASURE_GAIN[0]}-{MEASURE_GAIN[1]} "
                "against the truth on every measure that moves",
}


def resolve_characters(actor, target):
    """(actor rig, target rig) for ``eval synthetic --actor A --target T``: None or "default"
    is the default avatar; a file is loaded (:func:`load_character`); the actor gets
    turning eyes (:func:`capture2face.synth.actor_rig`). The actor rig is None for the
    default avatar (rendered by the default performance); the target defaults to the
    default avatar."""
    def load(which):
        return None if which is None or str(which) == "default" else load_character(which)

    actor_loaded = load(actor)
    target_rig = load(target) or default_avatar()
    return (None if actor_loaded is None else actor_rig(actor_loaded)), target_rig


def _arkit_weight_figures(truth, animation, target, use: np.ndarray) -> dict:
    """The target's solved weights against the actor's true ones, paired by ARKit name."""
    true_cols = arkit_columns(truth.blend_names)
    pairs = [(true_cols[name], m, name) for m, name in sorted(arkit_morphs(target.morph_names).items())
             if name in true_cols]
    if not pairs:
        return {"blendweight_morphs": 0}
    t_cols, p_cols, names = zip(*pairs)
    w_true = truth.blend_weights[use][:, list(t_cols)].astype(np.float64)
    w_pred = animation.blend_weights[use][:, list(p_cols)].astype(np.float64)
    return {"blendweight_morphs": len(pairs), "blendweight_mae": float(np.abs(w_pred - w_true).mean()),
            "baseline_zero_blendweight_mae": float(np.abs(w_true).mean()),
            **active_morph_figures(list(names), w_true, w_pred)}


def _mark_moved(chain: dict, measures_true: np.ndarray) -> dict:
    """``chain`` (:func:`measure_chain`) with ``moved`` and ``truth_range`` per measure."""
    for k, name in enumerate(MEASURES):
        span = float(np.ptp(measures_true[:, k]))
        chain[name]["truth_range"] = span
        chain[name]["moved"] = bool(span >= (MIN_RANGE_EYE if name in EYE_MEASURES else MIN_RANGE_IOD))
    return chain


def score_actor(track, animation, truth, actor, target) -> dict:
    """Compare a track and its retargeted animation with the truth of any actor.

    Args:
        track: the tracker's output on the synthetic clip (its ``neutral_frame`` the one
            retargeted from).
        animation: ``retarget(track, target)``.
        truth: the clip's ``SyntheticTruth``, rendered from ``actor`` (a FaceRig).
    Returns:
        dict of figures (see the module docstring), plain floats, ints, bools.
    """
    use = np.asarray(track.presence, bool) & np.asarray(truth.face_visible, bool)
    if not use.any():
        raise CaptureError("no frame of the synthetic clip has both a tracked and a visible face")
    measures_true = character_measures(actor, truth.bone_positions[use], truth.blend_weights[use])
    measures_solved = character_measures(target, animation.bone_positions[use], animation.blend_weights[use])
    chain = measure_chain(measures_true, source_measures(track)[use], measures_solved)
    return {
        "frames": int(track.n_frames),
        "frames_scored": int(use.sum()),
        "actor": actor.name,
        "target": target.name,
        **landmark_figures(track, truth, use),
        **_arkit_weight_figures(truth, animation, target, use),
        **mouth_figures(measures_true, measures_solved),
        **gaze_errors(animation, truth, use),
        "measures": _mark_moved(chain, measures_true),
        "arkit_curves": arkit_curve_figures(track, truth, use),
        "neutral_frame": int(track.neutral_frame),
    }


def actor_goals(result: dict) -> dict:
    """The :data:`ACTOR_GOALS` judged on a :func:`score_actor` result: per goal the curves
    or measures judged (those that move), those that miss, and ``met``."""
    curves = result["arkit_curves"]
    judged = [n for n in GOAL_CURVES if n in curves and curves[n]["moved"]]
    curve_miss = [n for n in judged if not (curves[n]["r"] >= CURVE_R_GOAL
                                            and curves[n]["mae"] < curves[n]["mediapipe_mae"])]
    measures = result["measures"]
    moving = [n for n in MEASURES if measures[n]["moved"]]
    lo, hi = MEASURE_GAIN
    measure_miss = [n for n in moving if not (measures[n]["character"]["r"] >= MEASURE_R_GOAL
                                              and lo <= measures[n]["character"]["gain"] <= hi)]
    out = {
        "arkit_curves": {"judged": judged, "missed": curve_miss, "met": bool(judged) and not curve_miss},
        "measures": {"judged": moving, "missed": measure_miss, "met": bool(moving) and not measure_miss},
    }
    for name, entry in out.items():
        entry["goal"] = ACTOR_GOALS[name]
    out["all_met"] = all(out[k]["met"] for k in ACTOR_GOALS)
    return out


def evaluate_actor_track(track, truth, actor, target, options: RetargetOptions | None = None,
                         auto_neutral: bool = True) -> dict:
    """Retarget a tracked synthetic clip of ``actor`` onto ``target`` (FaceRigs) from the
    truth's neutral hold and score it (:func:`score_actor`, with ``goals``); with
    ``auto_neutral`` also from the tracker's own rest (the nested ``auto_neutral`` block and
    ``rest_offsets_iod``, as ``eval synthetic``'s)."""
    if options is None:  # the gaze is estimated with the actor's eyes
        options = RetargetOptions(eye_radius_iod=eye_radius_iod(actor))
    auto, held = int(track.neutral_frame), truth.pose_frames("neutral")

    def run(neutral: int | None) -> dict:
        result = retarget_and_score(track, target, options, neutral,
                                    lambda posed, animation: score_actor(posed, animation, truth, actor, target))
        result["goals"] = actor_goals(result)
        return result

    first = int(held[0]) if len(held) else None
    result = run(first)
    result["neutral_frame_auto"] = auto
    if auto_neutral and first is not None:
        result["auto_neutral"] = run(None)
        result["rest_offsets_iod"] = rest_offsets(track, held)
    return result


def evaluate_actor_synthetic(actor=None, target=None, frames: int = 300, seed: int = 0, size: int = 512,
                             progress: bool = True, workdir: str | Path | None = None,
                             options: RetargetOptions | None = None, calibration: bool = False) -> dict:
    """Render ``frames`` frames of ``actor`` (a character file, a FaceRig, or None /
    "default": the default avatar), track them, retarget onto ``target`` (likewise; None:
    the default avatar) and score against the truth (:func:`evaluate_actor_track`).

    Args:
        workdir: where the synthetic clip goes (default: a temporary folder, removed).
        calibration: also render the actor's range-of-motion take (``synth --rom``, the same
            seed: its own head motion and light), calibrate on it, and score the performance
            calibrated; the result's ``calibration`` says what the take gave, with the
            ARKit curves' figures without it (``arkit_curves_uncalibrated``).
    """
    rig, target_rig = resolve_characters(actor, target)
    if calibration and rig is None:
        raise CaptureError("--calibration needs an ARKit character as the --actor (it performs the ROM take)")
    with tempfile.TemporaryDirectory(prefix="capture2face-eval-") as tmp:
        folder = Path(workdir) if workdir else Path(tmp)
        clip = synthesize(folder / "synthetic.mp4", SynthOptions(frames=frames, seed=seed, size=size),
                          progress=progress, actor=rig)
        track = _track(clip, actor, rig, progress)
        if calibration:
            rom = synthesize(folder / "rom.mp4", SynthOptions(seed=seed, size=size, rom=True), progress=progress,
                             actor=rig)
            learned = calibrate_take(_track(rom, actor, rig, progress))
            plain, track = track, attach(track, learned)
    source = rig if rig is not None else default_avatar()
    result = evaluate_actor_track(track, clip.truth, source, target_rig, options)
    result.update({"seed": int(seed), "size": int(size)})
    if calibration:
        use = np.asarray(plain.presence, bool) & np.asarray(clip.truth.face_visible, bool)
        held = clip.truth.pose_frames("neutral")
        posed = with_frame_rest(plain, int(held[0])) if len(held) else plain  # as the figures above are scored
        result["calibration"] = {
            "arkit_curves_uncalibrated": arkit_curve_figures(posed, clip.truth, use),
            "steps_found": [s.name for s in learned.steps if s.found],
            "steps_missing": [s.name for s in learned.steps if not s.found],
            "curves": {n: c["source"] for n, c in learned.curves.items()}, "warnings": learned.warnings}
    return result


def _track(clip, actor, rig, progress: bool):
    """The Track of a synthetic ``clip`` of ``actor``."""
    try:
        return track_clip(clip.video_path, TrackOptions(), progress=progress)
    except NoFaceError:  # the clip is ours: the cause is the actor, not its temporary video
        raise CaptureError(f"actor {_label(actor, rig)}: the tracker finds no face in the {clip.truth.n_frames} "
                           "frames rendered of it; the actor must be a character with a human face and "
                           "ARKit-named morphs") from None


def _label(actor, rig) -> str:
    """The actor as the user gave it: its file, else the rig's name."""
    if rig is None or actor is None or isinstance(actor, FaceRig):
        return rig.name if rig is not None else "default"
    return os.fspath(actor)


def actor_summary_line(result: dict, label: str = "") -> str:
    """One line: the goal curves' r (MediaPipe's), the measures' tracker and character gains."""
    curves = result["arkit_curves"]
    cs = ", ".join(f"{n} {curves[n]['r']:.2f} ({curves[n]['mediapipe_r']:.2f})" for n in GOAL_CURVES
                   if n in curves and curves[n]["moved"])
    ms = ", ".join(f"{n} {m['tracker']['gain']:.2f}/{m['character']['gain']:.2f} r {m['character']['r']:.2f}"
                   for n, m in result["measures"].items() if m["moved"])
    g = result["goals"]
    return (f"{label + ': ' if label else ''}{result['actor']} -> {result['target']}: curves r (MediaPipe's) "
            f"{cs}; measures tracker/character gain {ms}; goals met "
            f"{sum(g[k]['met'] for k in ACTOR_GOALS)}/{len(ACTOR_GOALS)}")

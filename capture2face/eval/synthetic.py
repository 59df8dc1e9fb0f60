"""Closed-loop accuracy: render a synthetic performance, track it, retarget it, compare.

``capture2face eval synthetic`` calls :func:`evaluate_synthetic`. The figures (all
dimensionless) and how each is measured:

* ``landmark_nme_iod``: mean landmark pixel error of the tracker (canonical 468) divided
  by the true inter-ocular pixel distance (landmarks 33 / 263) of the frame.
* ``bone_error_iod_median`` / ``_p95``: |retargeted - true| face-bone positions (head
  coordinates) divided by the target rig's inter-ocular distance (cm), over frames x bones.
* ``blendweight_mae``: mean |retargeted - true| morph weight over all morphs;
  ``mediapipe_blendshape_mae``: MediaPipe's own scores against the true weights of the
  morphs that share a name (``blendweight_mae_shared``: ours on that same subset).
* ``wrinkle_influence_mae``: mean |retargeted - true| per-vertex pose influence
  ``Inf(v, P)`` (Dutreve §5.2, what the renderer blends the wrinkle maps with), over
  F x P x the skin vertices that some moving bone skins. ``wrinkle_influence_mae_bone``:
  the same over per-bone influences (F x P x B, bones that move in some pose), which
  weighs a lid bone skinning a sliver of skin like a brow bone carrying the forehead.
* ``baseline_*``: the same figures for trivial predictions (rest bones, zero weights,
  zero influences): a figure is only worth as much as its distance to these.
  ``<figure>_ratio`` = figure / its trivial prediction (1 = no better than predicting
  nothing; lower is better), for every figure that has one (:data:`RATIOS`). The tracker's
  ``landmark_nme_iod`` has none (no trivial landmark prediction survives head motion).
* ``blendweight_active_r``: mean over the morphs *active* in the clip (true weight std
  above :data:`ACTIVE_STD`) of the Pearson r of solved against true weight over frames
  (``blendweight_active_r_per_morph``: name -> r; a morph the solve leaves constant scores
  0, as does the all-zero prediction); ``blendweight_active_mae``: the MAE over those
  morphs only (``_ratio`` against all zeros).
* ``mouth_open_gain`` / ``mouth_open_r``: the mouth opening (landmarks 13-14, in the
  rig's own rest inter-ocular units, ``fidelity.character_measures``) of the target rig
  deformed by the solved bones and weights, against the source rig deformed by the true
  ones: std(solved) / std(true), and Pearson r. The rest pose has gain 0.
* ``measures``: where expression amplitude is lost, per fidelity measure (mouth opening
  and width, brows, eyes; :data:`capture2face.measures.MEASURES`): ``tracker``: the
  tracker's own raw landmarks (as ``eval fidelity`` measures an actor) against the truth;
  ``character``: the solved character against the truth; ``character_vs_tracker``: the
  solved character against the tracker (what ``eval fidelity`` reports on real clips).
  Each is ``{"r", "gain"}``. The character cannot be expected to move more faithfully
  than the tracker sees: the tracker's figure is its floor.
* ``gaze_error_deg_median`` / ``_p95``: the angle in degrees between the true and the
  estimated gaze direction (``Animation.eye_rotation``, head coordinates) per eye and
  frame, over frames whose eye is open in the truth (its ``eyeBlink`` weight below 0.5:
  a closed lid hides the iris); ``gaze_yaw_error_deg_median`` / ``gaze_pitch_...``: the
  same per angle, with ``gaze_yaw_r`` / ``gaze_pitch_r`` (Pearson r against the truth);
  ``baseline_straight_gaze_error_deg_median``: the eyes kept straight ahead. The actor is
  the default avatar, so the gaze is estimated with its eye radius
  (``RetargetOptions.eye_radius_iod`` = ``retarget.gaze.eye_radius_iod(source)``) unless
  ``options`` are given.
* Retargeting starts from a frame the truth holds at neutral, and again from the
  tracker's own rest (each region's most relaxed frames; one tracking pass, two
  retargets): the second set of figures, same keys, is the nested ``auto_neutral`` block,
  so the cost of a bad rest shows; ``rest_offsets_iod``: that rest's brow height, lid
  openings and lip gap less the tracker's at the truth's neutral frames (IOD).
* ``goals``: the benchmark's goals (:data:`GOALS`, stated for 300 frames), each with the
  values it was judged on and ``met``; also inside ``auto_neutral``.

Cross-character (``target_variant``): the truth lives on the source avatar and has to be
carried onto the target to be compared. Both avatars share one topology, so the rest->rest
correspondence is known at every vertex. Definition used here: each bone's true
displacement is multiplied by the bone's *local* rest->rest linear map, the 3x3 matrix that
best maps the source's rest vertices around the bone onto the target's (least squares,
weighted by the bone's skinning weights, about their weighted centroids); morph weights
carry over unchanged. So the neutral maps onto the target's neutral exactly and motion
scales with the target's local proportions (a face 20 % wider moves 20 % further
sideways). The truth influences on the target are then the §5.1 influences of those
bones under the target's reference poses.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from capture2face.maths.stats import pearson
from capture2face.measures import MEASURES, character_measures, compare, source_measures
from capture2face.retarget import RetargetOptions, retarget, shared_blendshapes
from capture2face.retarget.arkit import arkit_curves
from capture2face.retarget.gaze import eye_radius_iod
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import gaze_directions
from capture2face.rig.influences import (
    region_influence,
    rig_influences,
    vertex_influences,
)
from capture2face.synth import SynthOptions, synthesize
from capture2face.topology import ARKIT_NAMES, IOD_PAIR, N_MESH
from capture2face.tracking import TrackOptions, track_clip
from capture2face.tracking.rest import GEOMETRY, actor_rest, rest_geometry, with_frame_rest

# A morph is active in a clip when its true weight's std over the scored frames exceeds this.
ACTIVE_STD = 0.02

# figure -> the trivial prediction it is divided by for ``<figure>_ratio``.
RATIOS: dict[str, str] = {
    "bone_error_iod_median": "baseline_rest_bone_error_iod_median",
    "bone_error_iod_p95": "baseline_rest_bone_error_iod_p95",
    "bone_error_iod_mean": "baseline_rest_bone_error_iod_mean",
    "blendweight_mae": "baseline_zero_blendweight_mae",
    "blendweight_active_mae": "baseline_zero_blendweight_active_mae",
    "gaze_error_deg_median": "baseline_straight_gaze_error_deg_median",
    "blendweight_mae_shared": "baseline_zero_blendweight_mae_shared",
    "mediapipe_blendshape_mae": "baseline_zero_blendweight_mae_shared",
    "wrinkle_influence_mae": "baseline_zero_influence_mae",
    "wrinkle_influence_mae_vertex": "baseline_zero_influence_mae",
    "wrinkle_influence_mae_bone": "baseline_zero_influence_mae_bone",
    "region_influence_mae": "baseline_zero_region_influence_mae",
}

# The benchmark's goals (on 300 frames): name -> description.
GOALS: dict[str, str] = {
    "bone_p95": "bone_error_iod_p95 <= 0.6 x the rest-pose figure",
    "blendweights": "blendweight_mae below the all-zero figure and blendweight_active_r >= 0.6",
    "wrinkles": "wrinkle_influence_mae <= 0.5 x the zero-influence figure",
}
GOAL_FRAMES = 300


def local_rest_maps(source, target) -> np.ndarray:
    """(B, 3, 3) per-bone linear maps from the source's rest shape to the target's.

    Each is the weighted least-squares fit of ``J (s_v - s_c) ~ (t_v - t_c)`` over the
    vertices a bone skins (weights = its skinning weights, centroids c weighted alike).
    Bones that skin no vertex get the global fit.
    """
    if source.vertices.shape != target.vertices.shape:
        raise ValueError("cross-character truth needs two rigs with the same topology")
    s = source.vertices.astype(np.float64)
    t = target.vertices.astype(np.float64)
    w = source.dense_skin_weights().astype(np.float64)  # (V, B)
    w = np.concatenate([np.ones((len(s), 1)), w], axis=1)  # column 0: global fit
    total = np.maximum(w.sum(0), 1e-12)
    sc = (w.T @ s) / total[:, None]  # (1+B, 3)
    tc = (w.T @ t) / total[:, None]
    ds = s[None] - sc[:, None]  # (1+B, V, 3)
    dt = t[None] - tc[:, None]
    sts = np.einsum("bv,bvi,bvj->bij", w.T, ds, ds)  # (1+B, 3, 3)
    stt = np.einsum("bv,bvi,bvj->bij", w.T, ds, dt)
    ok = w.sum(0) > 1e-6
    maps = np.empty((w.shape[1], 3, 3))
    # J^T = S_ss^{-1} S_st (row-vector convention: dt ~ ds @ J^T).
    maps[ok] = np.transpose(np.linalg.solve(sts[ok] + 1e-9 * np.eye(3), stt[ok]), (0, 2, 1))
    maps[~ok] = maps[0]
    return maps[1:]


def truth_on_target(bone_positions: np.ndarray, source, target) -> np.ndarray:
    """(F, B, 3) true source bones -> (F, B, 3) the truth carried onto ``target``
    (see the module docstring). Identity when ``target is source``."""
    if target is source:
        return np.asarray(bone_positions, np.float64)
    maps = local_rest_maps(source, target)
    disp = np.asarray(bone_positions, np.float64) - source.bone_rest
    return target.bone_rest + np.einsum("bij,fbj->fbi", maps, disp)


def _face_bones(rig) -> np.ndarray:
    return np.flatnonzero((np.arange(rig.n_bones) > 0) & (np.asarray(rig.bone_landmarks) >= 0))


def measure_chain(true: np.ndarray, seen: np.ndarray, solved: np.ndarray) -> dict:
    """Per fidelity measure, (r, gain) of the tracker (``seen``) and of the solved
    character against the truth, and of the character against the tracker; each (F, 6)
    :data:`~capture2face.measures.MEASURES` over the same frames."""
    out = {}
    for k, name in enumerate(MEASURES):
        pairs = {"tracker": (true, seen), "character": (true, solved), "character_vs_tracker": (seen, solved)}
        out[name] = {key: dict(zip(("r", "gain"), compare(a[:, k], b[:, k]))) for key, (a, b) in pairs.items()}
    return out


def add_ratios(result: dict) -> dict:
    """Add ``<figure>_ratio`` = figure / trivial prediction for each of :data:`RATIOS`
    present in ``result`` (NaN where the trivial figure is 0). Returns ``result``."""
    for key, base in RATIOS.items():
        if key in result and base in result:
            result[key + "_ratio"] = float(result[key] / result[base]) if result[base] > 0 else float("nan")
    return result


def goals(result: dict) -> dict:
    """The :data:`GOALS` judged on ``result`` (a :func:`score` dict with ratios): per goal
    its description, the values judged and ``met``; ``all_met``; ``frames_as_stated``:
    whether the clip has the :data:`GOAL_FRAMES` frames the goals are stated for."""
    bw_ratio, bw_r = result["blendweight_mae_ratio"], result["blendweight_active_r"]
    out = {
        "bone_p95": {"value": result["bone_error_iod_p95_ratio"], "limit": 0.6,
                     "met": bool(result["bone_error_iod_p95_ratio"] <= 0.6)},
        "blendweights": {"value": bw_ratio, "limit": 1.0, "active_r": bw_r, "active_r_limit": 0.6,
                         "met": bool(bw_ratio < 1.0 and bw_r >= 0.6)},
        "wrinkles": {"value": result["wrinkle_influence_mae_ratio"], "limit": 0.5,
                     "met": bool(result["wrinkle_influence_mae_ratio"] <= 0.5)},
    }
    for name, entry in out.items():
        entry["goal"] = GOALS[name]
    out["all_met"] = all(entry["met"] for entry in out.values())
    out["frames_as_stated"] = bool(result["frames"] == GOAL_FRAMES)
    return out


def summary_line(result: dict, label: str = "") -> str:
    """One line: the main figures as ratios to their trivial predictions, and the goals."""
    g = result["goals"]
    met = sum(g[k]["met"] for k in GOALS)
    return (f"{label + ': ' if label else ''}neutral frame {result['neutral_frame']}; "
            f"bone p95 {result['bone_error_iod_p95_ratio']:.2f}x rest, "
            f"median {result['bone_error_iod_median_ratio']:.2f}x; "
            f"weights MAE {result['blendweight_mae_ratio']:.2f}x zero, "
            f"active r {result['blendweight_active_r']:.2f} ({result['blendweight_active_morphs']} morphs); "
            f"wrinkles {result['wrinkle_influence_mae_ratio']:.2f}x zero; "
            f"mouth gain {result['mouth_open_gain']:.2f} r {result['mouth_open_r']:.2f} "
            f"(tracker's own {result['measures']['mouth_open']['tracker']['gain']:.2f}); "
            + (f"gaze error {result['gaze_error_deg_median']:.1f} deg median, "
               f"{result['gaze_error_deg_p95']:.1f} p95; " if "gaze_error_deg_median" in result else "")
            + f"goals met {met}/{len(GOALS)}"
            + ("" if g["frames_as_stated"] else f" (stated for {GOAL_FRAMES} frames)"))


def score(track, animation, truth, source, target) -> dict:
    """Compare a track and its retargeted animation with the synthetic truth.

    Args:
        track: the tracker's output on the synthetic clip.
        animation: ``retarget(track, target)``.
        truth: the clip's ``SyntheticTruth`` (rendered from ``source``).
        source, target: the rendered avatar and the one retargeted onto.
    Returns:
        dict of figures (see the module docstring), plain floats and ints.
    """
    use = np.asarray(track.presence, bool) & np.asarray(truth.face_visible, bool)
    if not use.any():
        raise ValueError("no frame has both a tracked and a visible face")
    true_bones = truth_on_target(truth.bone_positions, source, target)
    bones = _face_bones(target)
    bone_figures, bone_baselines = _bone_figures(animation, true_bones, target, bones, use)
    w_true = truth.blend_weights[use].astype(np.float64)
    w_pred = animation.blend_weights[use].astype(np.float64)
    # Fidelity measures of the source deformed by the truth and of the target by the solve.
    measures_true = character_measures(source, truth.bone_positions[use], truth.blend_weights[use])
    measures_solved = character_measures(target, animation.bone_positions[use], animation.blend_weights[use])
    wrinkle_figures, wrinkle_baselines = _wrinkle_figures(animation, true_bones, target, use)
    neutral = track.neutral_frame
    result = {
        "frames": int(track.n_frames),
        "frames_scored": int(use.sum()),
        **landmark_figures(track, truth, use),
        **bone_figures,
        "blendweight_mae": float(np.abs(w_pred - w_true).mean()),
        **_shared_blendshape_figures(track, target, w_true, w_pred, use),
        **active_morph_figures(list(target.morph_names), w_true, w_pred),
        **mouth_figures(measures_true, measures_solved),
        **gaze_errors(animation, truth, use),
        **wrinkle_figures,
        # Trivial predictors, for scale: rest bones, zero weights, zero influences.
        **bone_baselines,
        "baseline_zero_blendweight_mae": float(np.abs(w_true).mean()),
        **wrinkle_baselines,
        "measures": measure_chain(measures_true, source_measures(track)[use], measures_solved),
        "neutral_frame": int(neutral),
        "neutral_bone_offset_cm": float(np.abs(animation.bone_positions[neutral] - target.bone_rest).max()),
        "target": target.name,
        "arkit_curves": arkit_curve_figures(track, truth, use),
    }
    if target is not source:
        result.update(_cross_character_figures(animation, truth, source, target, bones, use))
    return add_ratios(result)


def landmark_figures(track, truth, use: np.ndarray) -> dict:
    """The tracker: landmark pixels against the projected truth, per frame / inter-ocular px."""
    lm_true = truth.landmarks_px[use, :N_MESH].astype(np.float64)
    lm_pred = track.landmarks_px[use, :N_MESH].astype(np.float64)
    iod_px = np.linalg.norm(lm_true[:, IOD_PAIR[1]] - lm_true[:, IOD_PAIR[0]], axis=1)
    lm_err = np.nanmean(np.linalg.norm(lm_pred - lm_true, axis=2), axis=1) / iod_px
    return {"landmark_nme_iod": float(np.mean(lm_err))}


def _bone_figures(animation, true_bones: np.ndarray, target, bones: np.ndarray,
                  use: np.ndarray) -> tuple[dict, dict]:
    """Bones, in head coordinates, on the target: the solve's errors, and (the baseline)
    those of the rest pose."""
    err = np.linalg.norm(animation.bone_positions[use][:, bones] - true_bones[use][:, bones], axis=2)
    err_iod = err / target.interocular()
    rest_err = np.linalg.norm(true_bones[use][:, bones] - target.bone_rest[bones], axis=2) / target.interocular()
    figures = {
        "bone_error_iod_median": float(np.median(err_iod)),
        "bone_error_iod_p95": float(np.percentile(err_iod, 95)),
        "bone_error_iod_mean": float(np.mean(err_iod)),
    }
    baselines = {
        "baseline_rest_bone_error_iod_median": float(np.median(rest_err)),
        "baseline_rest_bone_error_iod_p95": float(np.percentile(rest_err, 95)),
        "baseline_rest_bone_error_iod_mean": float(np.mean(rest_err)),
    }
    return figures, baselines


def _shared_blendshape_figures(track, target, w_true: np.ndarray, w_pred: np.ndarray, use: np.ndarray) -> dict:
    """MediaPipe's scores on the morphs that share a name (and ours on that subset); empty
    when no morph does."""
    shared = shared_blendshapes(target.morph_names, track.blendshape_names)
    if not shared:
        return {}
    ms, ss = np.array(shared).T
    return {
        "mediapipe_blendshape_mae": float(np.abs(track.blendshapes[use][:, ss] - w_true[:, ms]).mean()),
        "blendweight_mae_shared": float(np.abs(w_pred[:, ms] - w_true[:, ms]).mean()),
        "baseline_zero_blendweight_mae_shared": float(np.abs(w_true[:, ms]).mean()),
        "shared_morphs": len(shared),
    }


def active_morph_figures(names: list[str], w_true: np.ndarray, w_pred: np.ndarray) -> dict:
    """Morphs active in the clip: does the solve follow them (r), and by how much (MAE)?

    Args:
        names: the morph name of each column of ``w_true`` and ``w_pred`` (F, M).
    """
    active = np.flatnonzero(w_true.std(0) > ACTIVE_STD)
    per_morph = {str(names[m]): pearson(w_pred[:, m], w_true[:, m]) for m in active}
    return {
        "blendweight_active_morphs": int(len(active)),
        "blendweight_active_r": float(np.mean(list(per_morph.values()))) if len(active) else float("nan"),
        "blendweight_active_r_per_morph": per_morph,
        "blendweight_active_mae":
            float(np.abs(w_pred[:, active] - w_true[:, active]).mean()) if len(active) else float("nan"),
        "baseline_zero_blendweight_active_mae":
            float(np.abs(w_true[:, active]).mean()) if len(active) else float("nan"),
    }


def mouth_figures(measures_true: np.ndarray, measures_solved: np.ndarray) -> dict:
    """The mouth opening among the fidelity measures: the solve's gain and r against the truth."""
    mouth = list(MEASURES).index("mouth_open")
    mouth_true, mouth_pred = measures_true[:, mouth], measures_solved[:, mouth]
    s_true = float(np.std(mouth_true))
    return {
        "mouth_open_gain": float(np.std(mouth_pred) / s_true) if s_true > 1e-12 else float("nan"),
        "mouth_open_r": pearson(mouth_pred, mouth_true),
        "mouth_open_true_std_iod": s_true,
    }


def _wrinkle_figures(animation, true_bones: np.ndarray, target, use: np.ndarray) -> tuple[dict, dict]:
    """Wrinkle influence errors per vertex, per bone and per region, and (the baselines)
    those of zero influences."""
    # Per-bone influences, bones that move in some reference pose.
    # Recomputed (not the truth file's copy) so truth and prediction share the rig's
    # current bone groups.
    inf_true = rig_influences(true_bones, target)
    moving = np.linalg.norm(target.pose_bones - target.bone_rest, axis=2).max(0) > 1e-4
    inf_err = np.abs(animation.influences[use][:, :, moving] - inf_true[use][:, :, moving])
    # Per-vertex influences Inf(v, P) (what the renderer blends wrinkle maps with), over
    # the skin vertices some moving bone skins (the others are 0 in truth and prediction).
    skin = target.dense_skin_weights()[np.asarray(target.material) == 0].astype(np.float64)
    skin = skin[skin[:, moving].sum(1) > 1e-3]
    vertex_err = np.abs(vertex_influences(animation.influences[use] - inf_true[use], skin))
    region_true = region_influence(inf_true, target)
    figures = {
        # Per vertex: what the renderer shows (a bone skinning a large patch of
        # forehead matters more than a lid bone skinning a sliver); per bone alongside.
        "wrinkle_influence_mae": float(vertex_err.mean()),
        "wrinkle_influence_mae_bone": float(inf_err.mean()),
        "wrinkle_influence_mae_vertex": float(vertex_err.mean()),
        "region_influence_mae": float(np.abs(animation.region_influence[use] - region_true[use]).mean()),
    }
    baselines = {
        "baseline_zero_influence_mae": float(np.abs(vertex_influences(inf_true[use], skin)).mean()),
        "baseline_zero_influence_mae_bone": float(np.abs(inf_true[use][:, :, moving]).mean()),
        "baseline_zero_region_influence_mae": float(np.abs(region_true[use]).mean()),
    }
    return figures, baselines


def _cross_character_figures(animation, truth, source, target, bones: np.ndarray, use: np.ndarray) -> dict:
    """Onto another character: how the motion and the face sizes compare."""
    # Motion should scale with the target's face: ratio of mean bone displacements.
    moved_pred = np.linalg.norm(animation.bone_positions[use][:, bones] - target.bone_rest[bones], axis=2)
    moved_src = np.linalg.norm(truth.bone_positions[use][:, bones] - source.bone_rest[bones], axis=2)
    return {
        "motion_scale_ratio": float(moved_pred.mean() / moved_src.mean()),
        "face_size_ratio": float(target.face_size() / source.face_size()),
        "interocular_ratio": float(target.interocular() / source.interocular()),
    }


def gaze_errors(animation, truth, use: np.ndarray) -> dict:
    """Gaze figures (see the module docstring) over the frames ``use`` (F,) bool; empty
    when the truth or the animation has no gaze."""
    if getattr(truth, "eye_rotation", None) is None or getattr(animation, "eye_rotation", None) is None:
        return {}
    names = list(truth.blend_names)
    open_ = np.ones((len(truth.blend_weights), 2), bool)
    for e, name in enumerate(("eyeBlinkRight", "eyeBlinkLeft")):
        if name in names:
            open_[:, e] = truth.blend_weights[:, names.index(name)] < 0.5
    sel = use[:, None] & open_  # (F, 2)
    if not sel.any():
        return {}
    true_dir = gaze_directions(truth.eye_rotation)[sel]
    pred_dir = gaze_directions(animation.eye_rotation)[sel]
    err = np.degrees(np.arccos(np.clip((true_dir * pred_dir).sum(-1), -1.0, 1.0)))
    straight = np.degrees(np.arccos(np.clip(true_dir[:, 2], -1.0, 1.0)))
    return {
        "gaze_error_deg_median": float(np.median(err)),
        "gaze_error_deg_p95": float(np.percentile(err, 95)),
        "gaze_yaw_error_deg_median":
            float(np.median(np.abs(animation.eye_rotation[..., 0][sel] - truth.eye_rotation[..., 0][sel]))),
        "gaze_pitch_error_deg_median":
            float(np.median(np.abs(animation.eye_rotation[..., 1][sel] - truth.eye_rotation[..., 1][sel]))),
        "gaze_yaw_r": pearson(animation.eye_rotation[..., 0][sel], truth.eye_rotation[..., 0][sel]),
        "gaze_pitch_r": pearson(animation.eye_rotation[..., 1][sel], truth.eye_rotation[..., 1][sel]),
        "baseline_straight_gaze_error_deg_median": float(np.median(straight)),
        "gaze_eye_frames": int(sel.sum()),
    }


def synthetic_case(frames: int = 300, seed: int = 0, size: int = 512, folder: str | Path | None = None,
                   progress: bool = True, start: str = "rest"):
    """Render a synthetic performance of the default avatar into ``folder`` and track it
    (``start``: ``SynthOptions.start``).

    Returns:
        (SyntheticClip, Track).
    """
    with tempfile.TemporaryDirectory(prefix="capture2face-eval-") as tmp:
        folder = Path(folder) if folder else Path(tmp)
        clip = synthesize(folder / "synthetic.mp4", SynthOptions(frames=frames, seed=seed, size=size, start=start),
                          progress=progress)
        track = track_clip(clip.video_path, TrackOptions(), progress=progress)
    return clip, track


def evaluate_track(track, truth, target_variant: str | None = None,
                   options: RetargetOptions | None = None, true_neutral: bool = True,
                   auto_neutral: bool = True) -> dict:
    """Retarget a tracked synthetic clip of the default avatar onto the default avatar (or
    ``target_variant``) and score it against ``truth`` (see :func:`score`).

    ``true_neutral``: retarget from the first frame the truth holds at neutral, so the
    figures measure retargeting rather than the tracker's automatic neutral pick (which
    the result reports: ``neutral_frame_auto`` and ``neutral_frame_auto_offset_iod``, the
    largest true bone displacement on that frame).
    ``auto_neutral`` (with ``true_neutral``): also retarget the same track from the
    tracker's own rest (each region's, :mod:`capture2face.tracking.rest`) and score it into
    the nested ``auto_neutral`` block (same keys, its own ``goals``), with
    ``rest_offsets_iod`` (:func:`rest_offsets`).
    """
    auto = int(track.neutral_frame)
    held = truth.pose_frames("neutral")
    source = default_avatar()
    target = default_avatar(variant=target_variant) if target_variant else source
    if options is None:  # the actor's eyes are the source avatar's
        options = RetargetOptions(eye_radius_iod=eye_radius_iod(source))

    def run(neutral: int | None) -> dict:
        result = retarget_and_score(track, target, options, neutral,
                                    lambda posed, animation: score(posed, animation, truth, source, target))
        result["goals"] = goals(result)
        return result

    first = int(held[0]) if true_neutral and len(held) else None
    result = run(first)
    moved = np.linalg.norm(truth.bone_positions[auto] - source.bone_rest, axis=1).max()
    result["neutral_frame_auto"] = auto
    result["neutral_frame_auto_offset_iod"] = float(moved / source.interocular())
    if auto_neutral and first is not None:
        result["auto_neutral"] = run(None)
        result["rest_offsets_iod"] = rest_offsets(track, held)
    return result


def retarget_and_score(track, target, options: RetargetOptions, neutral: int | None, score_fn) -> dict:
    """``score_fn(track, animation)`` of ``track`` retargeted onto ``target``, resting on
    the frame ``neutral`` (:func:`~capture2face.tracking.rest.with_frame_rest`) or, None,
    on the tracker's own rest; with ``retarget_ms_per_frame``."""
    posed = track if neutral is None else with_frame_rest(track, neutral)
    start = time.perf_counter()
    animation = retarget(posed, target, options)
    elapsed = time.perf_counter() - start
    result = score_fn(posed, animation)
    result["retarget_ms_per_frame"] = 1000.0 * elapsed / max(1, track.n_frames)
    return result


def rest_offsets(track, neutral_frames: np.ndarray) -> dict[str, float]:
    """Each rest measure of the tracker's own rest (:mod:`capture2face.tracking.rest`: brow
    height, lid openings, lip gap) less the same measure at the frames the truth holds at
    neutral (the tracker's landmarks there, so its bias cancels), in IOD; {} without such
    frames."""
    if not len(neutral_frames):
        return {}
    at_neutral = np.median(rest_geometry(track.landmarks_head)[np.asarray(neutral_frames)], 0)
    rest = rest_geometry(actor_rest(track).landmarks[None])[0]
    return {name: round(float(rest[k] - at_neutral[k]), 4) for k, name in enumerate(GEOMETRY)}


def evaluate_synthetic(
    frames: int = 300,
    seed: int = 0,
    target_variant: str | None = None,
    size: int = 512,
    progress: bool = True,
    options: RetargetOptions | None = None,
    workdir: str | Path | None = None,
    start: str = "rest",
) -> dict:
    """Render ``frames`` synthetic frames of the default avatar, track them, retarget onto
    the same avatar (or ``target_variant``) and score against the truth.

    Args:
        workdir: where the synthetic clip goes (default: a temporary folder, removed).
        start: how the performance starts (``SynthOptions.start``); reported unless "rest".
    Returns:
        The figures of :func:`evaluate_track` (truth's neutral, and the tracker's pick in
        ``auto_neutral``), seed and size.
    """
    clip, track = synthetic_case(frames, seed, size, workdir, progress, start)
    result = evaluate_track(track, clip.truth, target_variant, options)
    result.update({"seed": int(seed), "size": int(size)})
    if start != "rest":  # the default's figures stay as they were
        result["start"] = start
    return result


# ---- ARKit curves against the truth (issue 22) ------------------------------------------------
# A curve "moved" in a clip when its true weight's range reaches this.
ARKIT_MOVED_RANGE = 0.2


def arkit_columns(morph_names: list[str]) -> dict[str, int]:
    """ARKit name -> the first of ``morph_names``' columns that carries it."""
    return {name: m for m, name in sorted(arkit_morphs(morph_names).items(), reverse=True)}


def arkit_curve_figures(track, truth, use: np.ndarray) -> dict:
    """Per ARKit name the actor has (and the tracker scores), over the frames ``use`` (F,)
    bool: this project's ARKit curve (``retarget.arkit.arkit_curves(track)``, calibrated at
    the track's rest) and MediaPipe's raw score against the true weight, and the
    all-zero prediction: ``{"r", "mae", "mediapipe_r", "mediapipe_mae", "zero_mae",
    "moved"}`` (``moved``: the truth's range is at least :data:`ARKIT_MOVED_RANGE`). Names
    in ARKit's order."""
    names = list(track.blendshape_names)
    ours = arkit_curves(track)[use].astype(np.float64)
    scores = np.asarray(track.blendshapes, np.float64)[use]
    true_cols = arkit_columns(truth.blend_names)
    out = {}
    for name in ARKIT_NAMES:
        if name not in true_cols or name not in names:
            continue
        s = names.index(name)
        t = truth.blend_weights[use, true_cols[name]].astype(np.float64)
        out[name] = {
            "r": pearson(ours[:, s], t), "mae": float(np.abs(ours[:, s] - t).mean()),
            "mediapipe_r": pearson(scores[:, s], t), "mediapipe_mae": float(np.abs(scores[:, s] - t).mean()),
            "zero_mae": float(np.abs(t).mean()), "moved": bool(np.ptp(t) >= ARKIT_MOVED_RANGE),
        }
    return out

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
* Retargeting starts from a frame the truth holds at neutral (the tracker's own pick is
  reported as ``neutral_frame_auto``).

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

from capture2face.retarget import RetargetOptions, retarget, shared_blendshapes
from capture2face.retarget.influences import region_influence, rig_influences, vertex_influences


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

    # Tracker: landmark pixels against the projected truth, per frame / inter-ocular px.
    lm_true = truth.landmarks_px[use, :468].astype(np.float64)
    lm_pred = track.landmarks_px[use, :468].astype(np.float64)
    iod_px = np.linalg.norm(lm_true[:, 263] - lm_true[:, 33], axis=1)
    lm_err = np.nanmean(np.linalg.norm(lm_pred - lm_true, axis=2), axis=1) / iod_px

    # Bones, in head coordinates, on the target.
    true_bones = truth_on_target(truth.bone_positions, source, target)
    bones = _face_bones(target)
    err = np.linalg.norm(animation.bone_positions[use][:, bones] - true_bones[use][:, bones], axis=2)
    err_iod = err / target.interocular()

    # Morph weights; MediaPipe's scores on the morphs that share a name.
    w_true = truth.blend_weights[use].astype(np.float64)
    w_pred = animation.blend_weights[use].astype(np.float64)
    shared = shared_blendshapes(target.morph_names, track.blendshape_names)
    result_mp = {}
    if shared:
        ms, ss = np.array(shared).T
        result_mp = {
            "mediapipe_blendshape_mae": float(np.abs(track.blendshapes[use][:, ss] - w_true[:, ms]).mean()),
            "blendweight_mae_shared": float(np.abs(w_pred[:, ms] - w_true[:, ms]).mean()),
            "shared_morphs": len(shared),
        }

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

    neutral = track.neutral_frame
    rest_err = np.linalg.norm(true_bones[use][:, bones] - target.bone_rest[bones], axis=2) / target.interocular()
    result = {
        "frames": int(track.n_frames),
        "frames_scored": int(use.sum()),
        "landmark_nme_iod": float(np.mean(lm_err)),
        "bone_error_iod_median": float(np.median(err_iod)),
        "bone_error_iod_p95": float(np.percentile(err_iod, 95)),
        "bone_error_iod_mean": float(np.mean(err_iod)),
        "blendweight_mae": float(np.abs(w_pred - w_true).mean()),
        **result_mp,
        # Per vertex: what the renderer shows (a bone skinning a large patch of
        # forehead matters more than a lid bone skinning a sliver); per bone alongside.
        "wrinkle_influence_mae": float(vertex_err.mean()),
        "wrinkle_influence_mae_bone": float(inf_err.mean()),
        "wrinkle_influence_mae_vertex": float(vertex_err.mean()),
        "region_influence_mae": float(np.abs(animation.region_influence[use] - region_true[use]).mean()),
        # Trivial predictors, for scale: rest bones, zero weights, zero influences.
        "baseline_rest_bone_error_iod_median": float(np.median(rest_err)),
        "baseline_rest_bone_error_iod_p95": float(np.percentile(rest_err, 95)),
        "baseline_zero_blendweight_mae": float(np.abs(w_true).mean()),
        "baseline_zero_influence_mae": float(np.abs(vertex_influences(inf_true[use], skin)).mean()),
        "baseline_zero_influence_mae_bone": float(np.abs(inf_true[use][:, :, moving]).mean()),
        "neutral_frame": int(neutral),
        "neutral_bone_offset_cm": float(np.abs(animation.bone_positions[neutral] - target.bone_rest).max()),
        "target": target.name,
    }
    if target is not source:
        # Motion should scale with the target's face: ratio of mean bone displacements.
        moved_pred = np.linalg.norm(animation.bone_positions[use][:, bones] - target.bone_rest[bones], axis=2)
        moved_src = np.linalg.norm(truth.bone_positions[use][:, bones] - source.bone_rest[bones], axis=2)
        result["motion_scale_ratio"] = float(moved_pred.mean() / moved_src.mean())
        result["face_size_ratio"] = float(target.face_size() / source.face_size())
        result["interocular_ratio"] = float(target.interocular() / source.interocular())
    return result


def synthetic_case(frames: int = 300, seed: int = 0, size: int = 512, folder: str | Path | None = None,
                   progress: bool = True):
    """Render a synthetic performance of the default avatar into ``folder`` and track it.

    Returns:
        (SyntheticClip, Track).
    """
    from capture2face.synth import SynthOptions, synthesize
    from capture2face.tracking import TrackOptions, track_clip

    with tempfile.TemporaryDirectory(prefix="capture2face-eval-") as tmp:
        folder = Path(folder) if folder else Path(tmp)
        clip = synthesize(folder / "synthetic.mp4", SynthOptions(frames=frames, seed=seed, size=size),
                          progress=progress)
        track = track_clip(clip.video_path, TrackOptions(), progress=progress)
    return clip, track


def evaluate_track(track, truth, target_variant: str | None = None,
                   options: RetargetOptions | None = None, true_neutral: bool = True) -> dict:
    """Retarget a tracked synthetic clip of the default avatar onto the default avatar (or
    ``target_variant``) and score it against ``truth`` (see :func:`score`).

    ``true_neutral``: retarget from the first frame the truth holds at neutral, so the
    figures measure retargeting rather than the tracker's automatic neutral pick (which
    the result reports: ``neutral_frame_auto`` and ``neutral_frame_auto_offset_iod``, the
    largest true bone displacement on that frame).
    """
    import dataclasses

    from capture2face.rig.avatar import default_avatar

    auto = int(track.neutral_frame)
    held = truth.pose_frames("neutral")
    if true_neutral and len(held):
        track = dataclasses.replace(track, neutral_frame=int(held[0]))
    source = default_avatar()
    target = default_avatar(variant=target_variant) if target_variant else source
    start = time.perf_counter()
    animation = retarget(track, target, options)
    elapsed = time.perf_counter() - start
    result = score(track, animation, truth, source, target)
    result["retarget_ms_per_frame"] = 1000.0 * elapsed / max(1, track.n_frames)
    moved = np.linalg.norm(truth.bone_positions[auto] - source.bone_rest, axis=1).max()
    result["neutral_frame_auto"] = auto
    result["neutral_frame_auto_offset_iod"] = float(moved / source.interocular())
    return result


def evaluate_synthetic(
    frames: int = 300,
    seed: int = 0,
    target_variant: str | None = None,
    size: int = 512,
    progress: bool = True,
    options: RetargetOptions | None = None,
    workdir: str | Path | None = None,
) -> dict:
    """Render ``frames`` synthetic frames of the default avatar, track them, retarget onto
    the same avatar (or ``target_variant``) and score against the truth.

    Args:
        workdir: where the synthetic clip goes (default: a temporary folder, removed).
    Returns:
        The figures of :func:`score`, the retargeting time per frame, seed and size.
    """
    clip, track = synthetic_case(frames, seed, size, workdir, progress)
    result = evaluate_track(track, clip.truth, target_variant, options)
    result.update({"seed": int(seed), "size": int(size)})
    return result

"""Retargeting: a ``Track`` (the source face) onto a ``FaceRig`` (the character) -> ``Animation``.

1. Feature points (Dutreve 2008): an RBF network trained at the neutral frame maps the
   source's landmarks (head coordinates) onto the character's feature points
   (:mod:`capture2face.retarget.rbf`).
2. Bones and morph weights that reproduce the mapped feature points through the rig's own
   deformation (morphs, then skinning), solved jointly with bounds, a ridge and a temporal
   smoothness term (:mod:`capture2face.retarget.solve`). A character whose mesh has no
   per-landmark vertices (an imported one with only bone landmarks) takes the network's
   output at the bone landmarks as bone positions, and MediaPipe's scores as the weights
   of its ARKit-named morphs.
3. Wrinkle influences (Dutreve 2009 §5.1-5.2) and zone weights
   (:mod:`capture2face.retarget.influences`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.retarget import influences as inf
from capture2face.retarget.animation import Animation
from capture2face.retarget.rbf import FeatureMap, fit_feature_map
from capture2face.retarget.solve import LinearSolver, linear_rig_model

__all__ = ["Animation", "RetargetOptions", "retarget", "retarget_ms_per_frame", "feature_correspondence"]


@dataclass
class RetargetOptions:
    """Retargeting settings (defaults chosen by ``capture2face eval synthetic``).

    Attributes:
        kernel: RBF kernel of the feature-point network.
        smoothing: RBF smoothing (0 = interpolate the neutral pairs exactly; the neutral
            frame maps exactly onto the target's neutral either way).
        epsilon: RBF shape parameter (only for kernels that need one).
        n_centers: RBF centres (a well-spread subset of the feature points; None = all).
        temporal_smoothness: weight of |x_f - x_{f-1}|^2 against the feature-point fit
            (unknowns scaled to unit feature-point motion).
        ridge: weight of |t_f|^2 on bone translations (keeps directions the feature
            points cannot see at rest).
        morph_ridge: weight of |w_f|^2 on morph weights.
        sparsity: weight of sum(w_f) (an L1 prior: few morphs at a time), in units of
            the scaled least-squares gradient.
        depth_weight: weight of the feature points' z (depth) residual against x and y.
        solve_blend_weights: solve the rig's morph weights with the bones; when False, or
            when the rig has no per-landmark vertices, morphs that share a name with a
            MediaPipe blendshape take its score and the others stay 0.
        joint_solve: solve bones from all feature points through the skinning (True), or
            take each bone's mapped landmark directly (False; for comparison).
        oval_weight: a-priori weight of the face-oval (silhouette) feature points.
        reweight_iterations: iteratively reweighted least squares: each pass weights
            every feature point by the inverse of its median squared residual over the
            clip (0 = one plain solve).
        reweight_floor: residual (cm) added in quadrature before inverting, so that
            points the rig fits perfectly do not take all the weight.
    """

    # Chosen on 300 synthetic frames (``capture2face eval synthetic``): thin-plate,
    # linear and cubic kernels with 64-128 centres all land within 0.001 IOD of bone error
    # of each other (the tracker's landmark error dominates); all centres is slightly worse
    # (it fits the tracker's neutral-frame noise) and 4x slower. The cubic polyharmonic
    # kernel needs no shape parameter (no epsilon to tune against face size) and is
    # cheaper to evaluate than the thin-plate spline's r^2 log r. Smoothing changed nothing
    # measurable: the neutral pairs are fitted exactly and the offset term keeps the
    # neutral exact anyway.
    kernel: str = "cubic"
    smoothing: float = 0.0
    epsilon: float | None = None
    n_centers: int | None = 96
    temporal_smoothness: float = 0.05
    ridge: float = 1e-4
    # Morph priors, a compromise measured both ways. MediaPipe's landmark error on the
    # synthetic face (~0.15 cm, mostly view-dependent, so temporal smoothing cannot remove
    # it) is as large as most morphs' motion. On 300 tracked synthetic frames, blendweight
    # MAE: 0.17 (morph_ridge 1e-4, no L1), 0.10 (0.1, 0.05: the default), 0.074 (1.0,
    # 0.05); all-zero weights score 0.065, MediaPipe's own scores 0.12. But on a
    # noise-free track the strong prior shrinks every weight to ~0 (MAE 0.057 = the
    # all-zero score) while the default still follows the motion (0.043) and weak priors
    # recover it exactly (morph_ridge=1e-4, sparsity=0: 0.0006).
    morph_ridge: float = 0.1
    sparsity: float = 0.05
    depth_weight: float = 1.0
    solve_blend_weights: bool = True
    joint_solve: bool = True
    # Feature-point reliability, chosen on seed 1 and checked on seeds 0 and 2 (300
    # synthetic frames; bone_error_iod_p95 0.072/0.063/0.084 -> 0.066/0.057/0.066,
    # blendweight_mae 0.094/0.089/0.097 -> 0.074/0.070/0.068; a floor of 0.02 cm or
    # one pass less costs ~0.001 p95, and so does giving the oval full weight). The tracker's error is
    # far from uniform: lip and chin landmarks err 2-3x more than eye and nose ones, and
    # the silhouette is a guess wherever there is no visible head outline.
    oval_weight: float = 0.1
    reweight_iterations: int = 2
    reweight_floor: float = 0.01


def feature_correspondence(rig) -> tuple[np.ndarray, np.ndarray, bool]:
    """Which tracker landmarks the rig has, and where.

    Returns:
        (landmarks (N,), target points (N, 3), per_vertex): with per-landmark vertices
        (``per_vertex`` True) every landmark that sits on a skin vertex; otherwise the bones'
        landmarks and the bones' rest positions.
    """
    lv = np.asarray(rig.landmark_vertices)
    # Skin only: iris landmarks follow the gaze, which the rig's eyeballs do not.
    has = np.flatnonzero(lv >= 0)
    has = has[np.asarray(rig.material)[lv[has]] == 0]
    if len(has) >= 3 * max(1, rig.n_bones - 1):
        return has, rig.vertices[lv[has]].astype(np.float64), True
    bones = np.flatnonzero(np.asarray(rig.bone_landmarks) >= 0)
    if len(bones) < 4:
        raise CaptureError(f"character '{rig.name}' has too few tracked feature points to retarget onto")
    return np.asarray(rig.bone_landmarks)[bones], rig.bone_rest[bones].astype(np.float64), False


def _mediapipe_weights(track, rig) -> np.ndarray:
    """(F, M) MediaPipe's scores for morphs that share a name, 0 for the others."""
    weights = np.zeros((track.n_frames, rig.n_morphs), np.float32)
    index = {n: i for i, n in enumerate(track.blendshape_names)}
    for m, name in enumerate(rig.morph_names):
        if name in index:
            weights[:, m] = track.blendshapes[:, index[name]]
    return np.clip(weights, 0.0, 1.0)


# MediaPipe's FACE_OVAL: the silhouette, which a mask-like character (or hair, or a beard)
# leaves the tracker guessing at.
FACE_OVAL = np.array([10, 21, 54, 58, 67, 93, 103, 109, 127, 132, 136, 148, 149, 150, 152, 162, 172, 176,
                      234, 251, 284, 288, 297, 323, 332, 338, 356, 361, 365, 377, 378, 379, 389, 397, 400, 454])


RELIABILITY_ADMM_ITERATIONS = 20


def landmark_prior_weights(landmarks: np.ndarray, options: RetargetOptions) -> np.ndarray:
    """(N,) a-priori reliability of each feature point (silhouette points down-weighted)."""
    w = np.ones(len(landmarks))
    w[np.isin(landmarks, FACE_OVAL)] = options.oval_weight
    return w


def _reliability(model, x: np.ndarray, mapped: np.ndarray, floor: float) -> np.ndarray:
    """(N,) inverse robust residual variance per feature point over the clip (IRLS),
    normalised to mean 1; ``floor`` (cm) bounds the weight of well-fitted points."""
    frames = len(x)
    fit = (x @ model.matrix.T).reshape(frames, -1, 3) + model.rest
    r2 = np.sum((mapped - fit) ** 2, axis=2)  # (F, N)
    var = np.median(r2, axis=0)  # robust to the frames a point is briefly lost on
    w = 1.0 / (var + floor**2)
    return w / w.mean()


def _fit_network(track, rig, landmarks, target, options: RetargetOptions) -> FeatureMap:
    neutral = track.landmarks_head[track.neutral_frame, landmarks]
    bone_lm = np.asarray(rig.bone_landmarks)
    keep = np.flatnonzero(np.isin(landmarks, bone_lm[bone_lm >= 0]))
    return fit_feature_map(
        neutral, target, kernel=options.kernel, smoothing=options.smoothing,
        epsilon=options.epsilon, n_centers=options.n_centers, keep_centers=keep,
    )


def _joint_solver(model, options: RetargetOptions, landmark_weights, morph_ridge: float, sparsity: float) -> LinearSolver:
    return LinearSolver(model, ridge=options.ridge, temporal=options.temporal_smoothness,
                        morph_ridge=morph_ridge, sparsity=sparsity,
                        axis_weights=(1.0, 1.0, options.depth_weight), landmark_weights=landmark_weights)


def solve_bones_weights(mapped: np.ndarray, rig, landmarks: np.ndarray, per_vertex: bool,
                        options: RetargetOptions, neutral: int | None = None
                        ) -> tuple[np.ndarray, np.ndarray | None]:
    """Bones (F, B, 3) and morph weights (F, M) (None = not solved) from mapped points.

    Args:
        mapped: (F, N, 3) the network's output (target feature points per frame).
        landmarks: (N,) the tracker landmarks they belong to.
        neutral: the neutral frame, pinned to rest bones and zero weights.
    """
    frames = mapped.shape[0]
    bones = np.repeat(rig.bone_rest[None].astype(np.float64), frames, 0)
    bone_lm = np.asarray(rig.bone_landmarks)
    slot = {int(l): i for i, l in enumerate(landmarks)}
    direct = [(b, slot[int(l)]) for b, l in enumerate(bone_lm) if b > 0 and int(l) in slot]
    if not per_vertex:  # imported character: bone = its mapped feature point
        for b, i in direct:
            bones[:, b] = mapped[:, i]
        return bones, None
    vertices = np.asarray(rig.landmark_vertices)[landmarks]
    solve_w = options.solve_blend_weights
    if options.joint_solve:
        model = linear_rig_model(rig, vertices, solve_morphs=solve_w)
        prior_w = landmark_prior_weights(landmarks, options)
        lw = prior_w
        # Reliability passes fit with weak morph priors: their residual is what the rig
        # cannot explain (tracker error), not motion the priors hold back, so a
        # perfect track keeps uniform weights. A short ADMM is enough for residuals (the
        # unbounded fit is worse: negative morphs soak up the tracker's error).
        for _ in range(options.reweight_iterations):
            solver = _joint_solver(model, options, lw, morph_ridge=1e-4, sparsity=0.0)
            solver.iterations = RELIABILITY_ADMM_ITERATIONS
            x = solver.solve(mapped, pin=neutral)
            lw = prior_w * _reliability(model, x, mapped, options.reweight_floor)
        x = _joint_solver(model, options, lw, options.morph_ridge, options.sparsity).solve(mapped, pin=neutral)
        nb = model.n_bone_vars
        bones[:, model.free_bones] += x[:, :nb].reshape(frames, -1, 3)
        if not solve_w:
            return bones, None
        weights = np.zeros((frames, rig.n_morphs))
        weights[:, model.morphs] = x[:, nb:]
        return bones, weights
    # Direct: each bone copies its landmark's motion; morphs explain what is left.
    rest_pts = rig.vertices[vertices].astype(np.float64)
    for b, i in direct:
        bones[:, b] += mapped[:, i] - rest_pts[i]
    if not solve_w:
        return bones, None
    skin = rig.dense_skin_weights()[vertices].astype(np.float64)
    skinned = np.einsum("nb,fbc->fnc", skin, bones - rig.bone_rest)
    residual = mapped - skinned
    model = linear_rig_model(rig.replace(skin_joints=np.zeros_like(rig.skin_joints)), vertices, True)
    x = LinearSolver(model, ridge=options.ridge, temporal=options.temporal_smoothness,
                         morph_ridge=options.morph_ridge, sparsity=options.sparsity,
                         axis_weights=(1.0, 1.0, options.depth_weight)).solve(residual, pin=neutral)
    weights = np.zeros((frames, rig.n_morphs))
    weights[:, model.morphs] = x[:, model.n_bone_vars:]
    return bones, weights


def retarget(track, rig, options: RetargetOptions | None = None) -> Animation:
    """Retarget a track onto a character.

    Args:
        track: :class:`~capture2face.tracking.track.Track` (landmarks in head coordinates,
            a neutral frame).
        rig: the target :class:`~capture2face.rig.face_rig.FaceRig`.
    Returns:
        :class:`Animation` with every field filled. Frames without a face carry what the
        track holds for them (interpolated or held landmarks); ``presence`` says which.
    """
    options = options or RetargetOptions()
    if track.n_frames == 0:
        raise CaptureError("the track has no frames to retarget")
    if not 0 <= track.neutral_frame < track.n_frames:
        raise CaptureError(f"neutral frame {track.neutral_frame} is outside the track's {track.n_frames} frames")
    landmarks, target, per_vertex = feature_correspondence(rig)
    network = _fit_network(track, rig, landmarks, target, options)
    mapped = network(track.landmarks_head[:, landmarks])  # (F, N, 3)
    bones, weights = solve_bones_weights(mapped, rig, landmarks, per_vertex, options, track.neutral_frame)
    if weights is None:
        weights = _mediapipe_weights(track, rig)
    bones = bones.astype(np.float32)
    bones[:, 0] = rig.bone_rest[0]
    weights = np.clip(weights, 0.0, 1.0).astype(np.float32)
    influences = inf.rig_influences(bones, rig)
    return Animation(
        times=np.asarray(track.times, np.float64),
        fps=float(track.fps),
        bone_names=list(rig.bone_names),
        bone_positions=bones,
        head_pose=np.asarray(track.head_pose, np.float32),
        blend_names=list(rig.morph_names),
        blend_weights=weights,
        pose_names=list(rig.pose_names),
        influences=influences,
        rest_influence=inf.rest_influence(influences),
        region_names=list(rig.region_names),
        region_influence=inf.region_influence(influences, rig),
        zone_names=list(rig.zone_names),
        zone_weights=inf.zone_weights(weights, rig.zone_table),
        mediapipe_blendshapes=np.asarray(track.blendshapes, np.float32),
        mediapipe_blendshape_names=list(track.blendshape_names),
        presence=np.asarray(track.presence, bool),
        character=rig.name,
    )


def retarget_ms_per_frame(track, rig, options: RetargetOptions | None = None, repeats: int = 3) -> float:
    """Wall time of :func:`retarget` (network fit, mapping, solve, influences, zones) in
    milliseconds per frame, the best of ``repeats`` runs."""
    best = np.inf
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        retarget(track, rig, options)
        best = min(best, time.perf_counter() - start)
    return 1000.0 * best / max(1, track.n_frames)

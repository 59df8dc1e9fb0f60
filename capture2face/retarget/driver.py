"""The retargeting driver: :func:`retarget` fits the feature-point network, solves bones
and morph weights window by window, and evaluates wrinkle influences and zone weights
(the steps are described in :mod:`capture2face.retarget`)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from capture2face import topology
from capture2face.errors import CaptureError
from capture2face.retarget import gaze
from capture2face.retarget.animation import Animation
from capture2face.retarget.arkit import arkit_curves
from capture2face.retarget.arkit_solve import (
    EYE_CONTOURS,
    CurveShifted,
    SteadiedMap,
    arkit_point_weights,
    mix_cap,
    morph_solve,
)
from capture2face.retarget.ranges import range_targets
from capture2face.retarget.rbf import FeatureMap, fit_feature_map
from capture2face.retarget.solve import LinearSolver, linear_rig_model
from capture2face.retarget.windows import MappedPoints, SpilledMedian, frame_windows
from capture2face.rig import influences as inf
from capture2face.rig.arkit_names import MORPH_PLACED, arkit_morphs, arkit_weights, drive_mode, solved_morphs
from capture2face.rig.avatar import close_lips
from capture2face.rig.feature_points import feature_correspondence, feature_positions
from capture2face.rig.lid_fill import actor_closing, fill_lids
from capture2face.rig.look_at import look_weights
from capture2face.rig.morph_conventions import apply_rules, one_blink
from capture2face.rig.mouth_fill import actor_mouth, fill_mouth
from capture2face.rig.open_fill import actor_opening, fill_opening, lips_round
from capture2face.tracking.rest import REGIONS, ActorRest, actor_rest, landmark_regions


@dataclass
class RetargetOptions:
    """Retargeting settings (how each default was chosen, with its figures: docs/tuning.md).

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
        depth_motion: how much of the tracker's depth (z) motion away from the neutral
            frame the feature-point network is given (1 = all of it).
        close_source_lips: fit the network on the source neutral with its lips closed
            (the character's neutral lips touch).
        solve_blend_weights: solve the rig's morph weights with the bones; when False, or
            when the rig has no per-landmark vertices, morphs that share a name with a
            MediaPipe blendshape take its score and the others stay 0.
        joint_solve: solve bones from all feature points through the skinning (True), or
            take each bone's mapped landmark directly (False; for comparison).
        oval_weight: a-priori weight of the face-oval (silhouette) feature points.
        eye_corner_weight: a-priori weight of the outer eye corners (landmarks 33, 263).
        mouth_corner_weight: a-priori weight of the mouth corners (landmarks 61, 291).
        reweight_iterations: iteratively reweighted least squares: each pass weights
            every feature point by the inverse of its median squared residual over the
            clip (0 = one plain solve).
        reweight_floor: residual (cm) added in quadrature before inverting, so that
            points the rig fits perfectly do not take all the weight.
        window_frames, window_overlap: the solve runs over windows of this many frames
            sharing this many with the next (:mod:`capture2face.retarget.windows`).
        eye_radius_iod: the actor's distance from eye centre to iris in inter-ocular
            distances, which turns the irises' motion into angles
            (:func:`capture2face.retarget.gaze.eye_rotation`); a human's by default.
        arkit_prior: an ARKit character (:mod:`capture2face.retarget.arkit_solve`): weight
            (cm^2, the fit's units) of |w - curve|^2 pulling each solved morph towards its
            ARKit curve.
        convention_prior: ``arkit_prior`` of a head of another convention (visemes,
            Rocketbox), its recipes the prior: its many look-alike shapes (a spread viseme
            against a round one, the jaw sideways) traded against each other at 0.1 and
            bared the teeth for an "O" (docs/characters.md).
        convention_mix_cap: the most a viseme set's lips' shapes may sum to in a frame
            (:func:`~capture2face.rig.morph_conventions.mix_morphs`); None: no cap. Off: at 1 the
            visemes-only head's cheeks darken less (d12 2.9 -> 2.3 %, d18 4.2 -> 2.5 %), but its
            mouth no longer widens as far as the actor's (d0 width gain 0.88 -> 0.38;
            docs/characters.md).
        arkit_morph_ridge, arkit_sparsity: ``morph_ridge`` and ``sparsity`` of its solve.
        arkit_min_motion: a morph moving no landmark by more than this (inter-ocular
            distances) takes its curve.
        arkit_other_weight: a-priori weight of the landmarks off the features' contours.
        arkit_pair_weight: a-priori weight of each expression pair's difference.
        arkit_pair_across: its weight across the pair's rest direction against along it.
        arkit_network_share, arkit_eye_share: the network's share of the mapped motion (the
            rest: the faces' similarity), off the eyes and on their lids.
        arkit_own_range: the lips' and brows' separations follow the actor's motion
            scaled onto the character's own range (:mod:`capture2face.retarget.ranges`);
            False: as the network maps them.
        arkit_antagonist: weight of the co-activation penalty on antagonist morphs
            (:data:`~capture2face.retarget.arkit_solve.ANTAGONISTS`), relative to the
            product of the two morphs' weighted landmark motion (0: none).
    """

    kernel: str = "cubic"
    smoothing: float = 0.0
    epsilon: float | None = None
    n_centers: int | None = 96
    temporal_smoothness: float = 0.05
    ridge: float = 1e-4
    morph_ridge: float = 0.1
    sparsity: float = 0.05
    depth_weight: float = 1.0
    depth_motion: float = 0.6
    close_source_lips: bool = True
    solve_blend_weights: bool = True
    joint_solve: bool = True
    oval_weight: float = 0.1
    eye_corner_weight: float = 20.0
    mouth_corner_weight: float = 5.0
    reweight_iterations: int = 2
    reweight_floor: float = 0.01
    window_frames: int = 1000
    window_overlap: int = 100
    eye_radius_iod: float = gaze.HUMAN_RADIUS_IOD
    arkit_prior: float = 0.1
    convention_prior: float = 10.0
    convention_mix_cap: float | None = None
    arkit_morph_ridge: float = 0.001
    arkit_sparsity: float = 0.0
    arkit_min_motion: float = 0.02
    arkit_other_weight: float = 0.1
    arkit_pair_weight: float = 30.0
    arkit_pair_across: float = 0.1
    arkit_network_share: float = 0.5
    arkit_eye_share: float = 1.0
    arkit_own_range: bool = True
    arkit_antagonist: float = 1.0


def shared_blendshapes(morph_names: list[str], blendshape_names: list[str]) -> list[tuple[int, int]]:
    """(morph index, blendshape index) of every morph that shares a name with a MediaPipe score."""
    index = {n: i for i, n in enumerate(blendshape_names)}
    return [(m, index[n]) for m, n in enumerate(morph_names) if n in index]


def _mediapipe_weights(track, rig) -> np.ndarray:
    """(F, M) MediaPipe's scores for morphs that share a name, 0 for the others."""
    weights = np.zeros((track.n_frames, rig.n_morphs), np.float32)
    for m, s in shared_blendshapes(rig.morph_names, track.blendshape_names):
        weights[:, m] = track.blendshapes[:, s]
    return np.clip(weights, 0.0, 1.0)


# MediaPipe's FACE_OVAL: the silhouette, which a mask-like character (or hair, or a beard)
# leaves the tracker guessing at.
FACE_OVAL = np.array(topology.FACE_OVAL)


# The outer eye corners (right, left): the reference the brows' height is seen against.
EYE_CORNERS = np.array(topology.EYE_OUTER_CORNERS)
# The mouth corners (right, left): where the mouth's width is seen.
MOUTH_CORNERS = np.array(topology.MOUTH_CORNERS)

RELIABILITY_ADMM_ITERATIONS = 20


def landmark_prior_weights(landmarks: np.ndarray, options: RetargetOptions) -> np.ndarray:
    """(N,) a-priori weight of each feature point (silhouette points down-weighted, outer
    eye corners and mouth corners up-weighted)."""
    w = np.ones(len(landmarks))
    w[np.isin(landmarks, FACE_OVAL)] = options.oval_weight
    w[np.isin(landmarks, EYE_CORNERS)] = options.eye_corner_weight
    w[np.isin(landmarks, MOUTH_CORNERS)] = options.mouth_corner_weight
    return w


def _residual2(model, x: np.ndarray, mapped: np.ndarray) -> np.ndarray:
    """(F, N) squared feature-point residual of the solution ``x`` (F, n)."""
    fit = (x @ model.matrix.T).reshape(len(x), -1, 3) + model.rest
    return np.sum((mapped - fit) ** 2, axis=2)


def _reliability(median_r2: np.ndarray, floor: float) -> np.ndarray:
    """(N,) inverse robust residual variance per feature point over the clip (IRLS) from
    the per-point median squared residual (robust to the frames a point is briefly lost
    on), normalised to mean 1; ``floor`` (cm) bounds the weight of well-fitted points."""
    w = 1.0 / (median_r2 + floor**2)
    return w / w.mean()


def _fit_network(rest: ActorRest, rig, landmarks, target, options: RetargetOptions) -> FeatureMap:
    neutral = np.asarray(rest.face, np.float64)
    if options.close_source_lips:
        neutral = close_lips(neutral)
    neutral = neutral[landmarks]
    bone_lm = np.asarray(rig.bone_landmarks)
    keep = np.flatnonzero(np.isin(landmarks, bone_lm[bone_lm >= 0]))
    return fit_feature_map(
        neutral, target, kernel=options.kernel, smoothing=options.smoothing,
        epsilon=options.epsilon, n_centers=options.n_centers, keep_centers=keep,
        depth_motion=options.depth_motion,
    )


def _joint_solver(model, options: RetargetOptions, landmark_weights, morph_ridge: float, sparsity: float,
                  prior_strength: np.ndarray | None = None, antagonists: np.ndarray | None = None,
                  mix: np.ndarray | None = None) -> LinearSolver:
    return LinearSolver(model, ridge=options.ridge, temporal=options.temporal_smoothness,
                        morph_ridge=morph_ridge, sparsity=sparsity,
                        axis_weights=(1.0, 1.0, options.depth_weight), landmark_weights=landmark_weights,
                        prior_strength=prior_strength, antagonists=antagonists,
                        antagonist_strength=options.arkit_antagonist if antagonists is not None else 0.0, mix=mix)


def solve_windows(mapped, model, point_weights: np.ndarray, options: RetargetOptions, neutral: int | None,
                  prior: np.ndarray | None = None, prior_strength: np.ndarray | None = None,
                  antagonists: np.ndarray | None = None, steady: np.ndarray | None = None,
                  mix: np.ndarray | None = None, cap: np.ndarray | None = None):
    """Yield (window, x (k, n)) for every window of ``mapped``: the joint solve of the
    :class:`~capture2face.retarget.solve.LinearRigModel`'s unknowns, after the reliability
    passes (which fit without the prior).

    Args:
        mapped: target feature points by window (:class:`MappedPoints` or alike).
        point_weights: (N,) a-priori weight of each feature point
            (:func:`landmark_prior_weights`).
        prior: (F, n) values the unknowns are pulled towards with ``prior_strength`` (n,).
        antagonists: (P, 2) unknowns whose co-activation the final solve penalises
            (``options.arkit_antagonist``).
        steady: feature points whose reliability is at least the mean's (1): targets
            whose residual is the character's shortfall, not the tracker's noise.
        mix, cap: (G,) unknowns whose weights the final solve caps to sum at most ``cap``
            (F,) per frame (:func:`~capture2face.retarget.arkit_solve.mix_cap`); None: no cap.
    """
    prior_w = np.asarray(point_weights, np.float64)
    lw = prior_w
    # Reliability passes fit with weak morph priors: their residual is what the rig
    # cannot explain (tracker error), not motion the priors hold back, so a
    # perfect track keeps uniform weights. A short ADMM is enough for residuals (the
    # unbounded fit is worse: negative morphs soak up the tracker's error).
    for _ in range(options.reweight_iterations):
        solver = _joint_solver(model, options, lw, morph_ridge=1e-4, sparsity=0.0)
        solver.iterations = RELIABILITY_ADMM_ITERATIONS
        with SpilledMedian(len(prior_w)) as r2:
            for w in mapped.windows:
                pts = mapped.read(w)
                r2.add(_residual2(model, solver.solve(pts, pin=w.pin(neutral))[w.own], pts[w.own]))
            reliability = _reliability(r2.median(), options.reweight_floor)
            if steady is not None:
                reliability[steady] = np.maximum(reliability[steady], 1.0)
            lw = prior_w * reliability
    solver = _joint_solver(model, options, lw, options.morph_ridge, options.sparsity, prior_strength, antagonists,
                           mix)
    for w in mapped.windows:
        yield w, solver.solve(mapped.read(w), pin=w.pin(neutral),
                              prior=None if prior is None else prior[w.start:w.stop],
                              cap=None if cap is None else cap[w.start:w.stop])


class _Blend:
    """Bones (F, B, 3) and weights (F, M) float32 assembled from cross-faded windows."""

    def __init__(self, frames: int, rig, weights: bool):
        self.bones = np.zeros((frames, rig.n_bones, 3), np.float32)
        self.weights = np.zeros((frames, rig.n_morphs), np.float32) if weights else None

    def add(self, w, bones: np.ndarray, weights: np.ndarray | None) -> None:
        fade = w.fade[:, None]
        self.bones[w.start:w.stop] += fade[:, :, None] * bones
        if self.weights is not None:
            self.weights[w.start:w.stop] += fade * weights


def solve_bones_weights(mapped: MappedPoints, rig, landmarks: np.ndarray, per_vertex: bool,
                        options: RetargetOptions, neutral: int | None = None
                        ) -> tuple[np.ndarray, np.ndarray | None]:
    """Bones (F, B, 3) and morph weights (F, M) float32 (None = not solved) from the
    mapped points, window by window.

    Args:
        mapped: the network's output (target feature points per frame), by window.
        landmarks: (N,) the tracker landmarks they belong to.
        neutral: a frame pinned to rest bones and zero weights (a rest of one frame), or None.
    """
    rest = rig.bone_rest.astype(np.float64)
    bone_lm = np.asarray(rig.bone_landmarks)
    slot = {int(lm): i for i, lm in enumerate(landmarks)}
    direct = [(b, slot[int(lm)]) for b, lm in enumerate(bone_lm) if b > 0 and int(lm) in slot]
    solve_w = options.solve_blend_weights and per_vertex
    out = _Blend(mapped.frames, rig, solve_w)
    if not per_vertex:  # imported character: bone = its mapped feature point
        for w in mapped.windows:
            pts = mapped.read(w)
            bones = np.repeat(rest[None], len(pts), 0)
            for b, i in direct:
                bones[:, b] = pts[:, i]
            out.add(w, bones, None)
        return out.bones, None
    vertices = np.asarray(rig.landmark_vertices)[landmarks]
    if options.joint_solve:
        model = linear_rig_model(rig, vertices, solve_morphs=solve_w)
        nb = model.n_bone_vars
        for w, x in solve_windows(mapped, model, landmark_prior_weights(landmarks, options), options, neutral):
            bones = np.repeat(rest[None], len(x), 0)
            bones[:, model.free_bones] += x[:, :nb].reshape(len(x), -1, 3)
            weights = None
            if solve_w:
                weights = np.zeros((len(x), rig.n_morphs))
                weights[:, model.morphs] = x[:, nb:]
            out.add(w, bones, weights)
        return out.bones, out.weights
    # Direct: each bone copies its landmark's motion; morphs explain what is left.
    rest_pts = rig.vertices[vertices].astype(np.float64)
    skin = rig.dense_skin_weights()[vertices].astype(np.float64)
    model = linear_rig_model(rig.replace(skin_joints=np.zeros_like(rig.skin_joints)), vertices, True)
    solver = _joint_solver(model, options, None, options.morph_ridge, options.sparsity)
    for w in mapped.windows:
        pts = mapped.read(w)
        bones = np.repeat(rest[None], len(pts), 0)
        for b, i in direct:
            bones[:, b] += pts[:, i] - rest_pts[i]
        weights = None
        if solve_w:
            residual = pts - np.einsum("nb,fbc->fnc", skin, bones - rest)
            x = solver.solve(residual, pin=w.pin(neutral))
            weights = np.zeros((len(pts), rig.n_morphs))
            weights[:, model.morphs] = x[:, model.n_bone_vars:]
        out.add(w, bones, weights)
    return out.bones, out.weights


def _per_frame(fn, *arrays, chunk: int = 2048) -> np.ndarray:
    """``fn(*arrays)`` for a per-frame function, evaluated ``chunk`` frames at a time
    (its float64 temporaries stay bounded on long clips)."""
    frames = len(arrays[0])
    first = fn(*(a[:chunk] for a in arrays))
    if frames <= chunk:
        return first
    out = np.empty((frames,) + first.shape[1:], first.dtype)
    out[:chunk] = first
    for s in range(chunk, frames, chunk):
        out[s:s + chunk] = fn(*(a[s:s + chunk] for a in arrays))
    return out


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
    rest = actor_rest(track)
    # The solve's matrices are small (~100 x 100): BLAS threads only add synchronisation,
    # which on a loaded 2-core machine made a 105 x 105 eigendecomposition take 77 ms
    # instead of 1 ms. One thread is the fast choice at these sizes.
    with threadpool_limits(limits=1, user_api="blas"):
        return _retarget(track, rest, rig, options)


def _retarget(track, rest: ActorRest, rig, options: RetargetOptions) -> Animation:
    if drive_mode(rig) == "arkit":
        return _retarget_arkit(track, rest, rig, options)
    landmarks, target, per_vertex = feature_correspondence(rig)
    network = _fit_network(rest, rig, landmarks, target, options)
    windows = frame_windows(track.n_frames, options.window_frames, options.window_overlap)
    reads = 1 + (options.reweight_iterations if per_vertex and options.joint_solve else 0)
    with MappedPoints(track.landmarks_head, network, landmarks, windows, reads) as mapped:
        bones, weights = solve_bones_weights(mapped, rig, landmarks, per_vertex, options, rest.single_frame)
    if weights is None:
        weights = _mediapipe_weights(track, rig)
    return _animation(track, rest, rig, bones, weights, arkit_curves(track, rest), options)


def _retarget_arkit(track, rest: ActorRest, rig, options: RetargetOptions) -> Animation:
    """A character without face bones: its morph weights are solved from the feature
    points, with the clip's ARKit curves (which already have ARKit meaning,
    :func:`~capture2face.retarget.arkit.arkit_curves`) as the prior and as the weights of
    what the points cannot see (:mod:`capture2face.retarget.arkit_solve`); without
    landmark points on its skin (or ``solve_blend_weights`` off) its ARKit-named morphs
    take the curves. A character without ARKit names (visemes, VRM presets) takes its
    morphs' recipes of the curves (:mod:`capture2face.rig.morph_conventions`), with its
    VRM expression rules. Bones stay at rest (the head rotation is the animation's head pose)."""
    curves = arkit_curves(track, rest)
    weights = arkit_weights(list(track.blendshape_names), curves, rig.morph_names)
    landmarks = _skin_landmarks(rig)
    if options.solve_blend_weights and landmarks is not None and solved_morphs(rig):
        weights = _solve_arkit_weights(track, rest, rig, landmarks, weights, options)
    if rig.landmark_source == MORPH_PLACED and not arkit_morphs(rig.morph_names):  # its recipes at its own range
        opening = actor_opening(track.landmarks_head, rest.landmarks)
        weights = fill_opening(weights, rig, opening, lips_round(list(track.blendshape_names), curves))
        weights = fill_mouth(weights, rig, actor_mouth(track.landmarks_head, rest.landmarks))
    if rig.look_ranges is not None:  # a VRM's look presets turn by its own range tables
        weights = look_weights(weights, rig.morph_names, rig.look_ranges, _gaze(track, rest, options))
    if not arkit_morphs(rig.morph_names):
        if rig.landmark_source == MORPH_PLACED:  # lids at the actor's closing
            weights = fill_lids(weights, rig, actor_closing(track.landmarks_head, rest.landmarks))
        weights = one_blink(weights, rig.morph_names, rig.morph_rules)  # a VRM's blinks close each eye once
    weights = apply_rules(weights, rig.morph_rules)
    bones = np.repeat(rig.bone_rest[None].astype(np.float32), track.n_frames, 0)
    # Automatic feature points (character.auto_wrinkles) measure the influences where the
    # morphs carry them; as bones they stay at rest (the morphs deform the face).
    influence = _per_frame(lambda w: feature_positions(rig, w), weights)
    if not arkit_morphs(rig.morph_names):
        # Its recipes keep some presets on at the actor's rest (d12: Sorrow 0.18 from
        # browInnerUp 0.2): the features' places there are the influences' rest, so its
        # wrinkles are 0 while the actor rests.
        influence -= feature_positions(rig, weights[[track.neutral_frame]]) - rig.bone_rest
    return _animation(track, rest, rig, bones, weights, curves, options, influence_bones=influence)


def _skin_landmarks(rig) -> np.ndarray | None:
    """(N,) the tracker landmarks on the rig's skin, or None when it has too few of them
    (a character imported without its landmarks cast)."""
    try:
        landmarks, _, per_vertex = feature_correspondence(rig)
    except CaptureError:
        return None
    return landmarks if per_vertex else None


def _solve_arkit_weights(track, rest: ActorRest, rig, landmarks: np.ndarray, prior: np.ndarray,
                         options: RetargetOptions) -> np.ndarray:
    """(F, M) float32 morph weights of an ARKit character solved from the mapped feature
    points at ``landmarks`` (N,), ``prior`` (F, M) the curves as morph weights."""
    solve = morph_solve(rig, landmarks, options.arkit_min_motion, options.arkit_pair_across)
    point_weights = arkit_point_weights(landmarks, landmark_prior_weights(landmarks, options),
                                        options.arkit_other_weight, options.arkit_pair_weight)
    options = dataclasses.replace(options, morph_ridge=options.arkit_morph_ridge, sparsity=options.arkit_sparsity)
    network = SteadiedMap(_fit_network(rest, rig, landmarks, solve.model.rest[:len(landmarks)], options),
                          np.where(np.isin(landmarks, EYE_CONTOURS), options.arkit_eye_share,
                                   options.arkit_network_share))
    ranged = range_targets(solve, landmarks, network.network.source_neutral) if options.arkit_own_range else None
    if ranged is not None and ranged.weights is not None:
        point_weights[ranged.rows] *= ranged.weights  # a brow of another shape: its mid pair leads
    windows = frame_windows(track.n_frames, options.window_frames, options.window_overlap)
    weights = np.zeros_like(prior)
    weights[:, solve.fixed] = prior[:, solve.fixed]
    solved, nf = solve.model.morphs, solve.model.n_free_vars
    strength = np.zeros(solve.model.matrix.shape[1])
    strength[nf:] = options.arkit_prior if arkit_morphs(rig.morph_names) else options.convention_prior
    prior_x = np.zeros((track.n_frames, len(strength)), np.float32)
    prior_x[:, nf:] = prior[:, solved]
    with MappedPoints(track.landmarks_head, network, landmarks, windows, 1 + options.reweight_iterations) as mapped:
        for w, x in solve_windows(CurveShifted(mapped, solve, prior, ranged), solve.model, point_weights, options,
                                  rest.single_frame, prior=prior_x, prior_strength=strength,
                                  antagonists=solve.antagonists, steady=_steady_pairs(rig, ranged),
                                  mix=solve.mix_unknowns(), cap=mix_cap(solve, prior, options.convention_mix_cap)):
            weights[w.start:w.stop, solved] += (w.fade[:, None] * x[:, nf:]).astype(np.float32)
    if solve.twins is not None and len(solve.twins):
        weights[:, solve.twins[:, 0]] = weights[:, solve.twins[:, 1]]
    return weights


def _steady_pairs(rig, ranged) -> np.ndarray | None:
    """The model's points whose reliability the solve holds at least at the mean's: on a
    head of another convention, the ranged pairs (:mod:`~capture2face.retarget.ranges`).
    Their targets are the actor's own separations at the head's range; a residual there is
    how far the head falls short (Rocketbox's mouth at d0's held wide smile, 1.5 cm), and
    down-weighting it as a noisy point handed the mouth to the recipes, which the strong
    ``convention_prior`` holds (d0 mouth width gain 0.45, the pair's weight 30 -> 0.4).
    ARKit heads keep the reweighting as it was (their weak prior; not measured there)."""
    if ranged is None or arkit_morphs(rig.morph_names):
        return None
    return np.asarray(ranged.rows)


def _gaze(track, rest: ActorRest, options: RetargetOptions) -> np.ndarray | None:
    """(F, 2, 2) eye yaw and pitch (degrees) from the tracked irises; None for a track
    without iris landmarks."""
    if track.landmarks_head.shape[1] < topology.N_LANDMARKS:
        return None
    return gaze.eye_rotation(track.landmarks_head, rest.landmarks, options.eye_radius_iod)


# The regions whose wrinkles are measured from their own rest (wrinkle_reference). The
# eyes' and the mouth's rest frames lie with the whole face's, which the network maps onto
# the character's rest; a shift measured there only adds noise, amplified where a reference
# pose moves a point little (a chin feature 0.06 cm: a 0.1 cm shift folded an ICT head's
# chin at rest, 0.61).
WRINKLE_REST_REGIONS = ("brows",)


def wrinkle_reference(bones: np.ndarray, rig, rest: ActorRest) -> np.ndarray:
    """(B, 3) where each bone of the :data:`WRINKLE_REST_REGIONS` sits at the actor's rest
    of its region, less its rest position (0 for the others): the wrinkles' reference poses
    are measured from there.

    The network maps the whole face's rest onto the character's rest, but a region's own
    rest can lie elsewhere: brows raised on the face's calmest frames, or head coordinates
    that move with the jaw (MediaPipe's fitted head pose shrinks the upper face as the jaw
    opens: brows 2 mm lower while talking on one clip, frown lines through all of it).
    Measured from the bones' median over their region's rest frames, a wrinkle appears only
    where the region leaves its own rest. Zero for a rest of one frame (pinned to rest) and
    for one from outside the clip (no frames).

    Args:
        bones: (F, B, 3) the bones (or feature points) the influences are evaluated on.
    """
    shift = np.zeros((rig.n_bones, 3), np.float32)
    regions = landmark_regions()
    for b, lm in enumerate(np.asarray(rig.bone_landmarks)):
        region = REGIONS[regions[lm]] if 0 <= lm < len(regions) else None
        frames = rest.frames.get(region, ()) if region in WRINKLE_REST_REGIONS else ()
        if b > 0 and len(frames):
            shift[b] = np.median(np.asarray(bones[np.asarray(frames)][:, b], np.float64), 0) - rig.bone_rest[b]
    return shift


def _animation(track, rest: ActorRest, rig, bones: np.ndarray, weights: np.ndarray, curves: np.ndarray,
               options: RetargetOptions, influence_bones: np.ndarray | None = None) -> Animation:
    """The Animation of solved bones (F, B, 3) and morph weights (F, M): the head bone
    pinned to rest, weights clipped to [0, 1], influences (from ``influence_bones``,
    default ``bones``), regions and zones evaluated, the gaze estimated."""
    bones[:, 0] = rig.bone_rest[0]
    weights = np.clip(weights, 0.0, 1.0).astype(np.float32, copy=False)
    source = bones if influence_bones is None else influence_bones
    shift = wrinkle_reference(source, rig, rest)
    influences = _per_frame(lambda b: inf.rig_influences(b - shift, rig), source)
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
        rest_influence=_per_frame(inf.rest_influence, influences),
        region_names=list(rig.region_names),
        region_influence=_per_frame(lambda i: inf.region_influence(i, rig), influences),
        zone_names=list(rig.zone_names),
        zone_weights=_per_frame(lambda w: inf.zone_weights(w, rig.zone_table), weights),
        mediapipe_blendshapes=np.asarray(track.blendshapes, np.float32),
        mediapipe_blendshape_names=list(track.blendshape_names),
        presence=np.asarray(track.presence, bool),
        character=rig.name,
        arkit_names=list(track.blendshape_names),
        arkit_weights=curves,
        eye_rotation=_gaze(track, rest, options),
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

"""Expression fidelity on real clips (no ground truth needed): does the character do what
the actor does, and as much?

The measures of ``capture2face eval fidelity`` (:mod:`capture2face.eval.fidelity`). Per clip, six geometric
measures of the face (:data:`MEASURES`), each in inter-ocular units (IOD, landmarks
33-263 at the neutral frame); the eye openings are relative to the face's own opening at
the neutral frame instead (a character keeps its own eye size):

* **source**: the tracker's raw landmarks (``Track.landmarks_px``/``landmarks_depth``, no
  project filtering), the head rotation removed with the tracker's own transformation
  matrix, low-passed at 8 Hz (zero phase);
* **character**: the rig deformed by the animation (morphs, then skinning) at the same
  landmark vertices;
* **direct**: the simplest alternative users have, the rig's ARKit-named morphs driven
  by the tracker's raw scores (bones at rest).

Per measure: Pearson r over the tracked frames and gain = std(character) / std(source).
A measure is judged where the source moves enough to judge it (range >= 0.04 IOD; eyes
0.3 of their neutral opening): faithful when r >= 0.9 and 0.8 <= gain <= 1.25.
The ARKit curves (``Animation.arkit_weights`` when present, else the tracker's scores)
are judged against the same geometry: JawOpen vs mouth opening, EyeBlink vs eye opening
(negated), BrowInnerUp vs brow height.
The gaze (``Animation.eye_rotation``, from the irises' geometry) is judged against the
tracker's own gaze scores: each eye's yaw against its eyeLookIn/Out difference (towards
the subject's left: left eye out - in, right eye in - out), pitch against eyeLookDown -
eyeLookUp; a yaw is judged where that difference moves (std >= :data:`MIN_GAZE_STD`),
goal r >= :data:`GAZE_R_GOAL`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from capture2face.errors import CaptureError
from capture2face.maths.stats import pearson
from capture2face.rig.arkit_names import GAZE_SCORES, arkit_morphs, arkit_weights, drive_mode, solved_morphs
from capture2face.rig.face_rig import landmark_points, landmark_support
from capture2face.rig.morph_conventions import recipe_poses
from capture2face.topology import (
    BROW_HEIGHT_PAIRS,
    IOD_PAIR,
    LIDS_LEFT,
    LIDS_RIGHT,
    LIP_GAP,
    MOUTH_CORNERS,
)
from capture2face.tracking.head_pose import head_landmarks
from capture2face.tracking.rest import actor_rest

# name -> (landmark a, landmark b): the measure is |p_a - p_b|.
MEASURES: dict[str, tuple[int, int]] = {
    "mouth_open": LIP_GAP,
    "mouth_width": MOUTH_CORNERS,
    "brow_right": BROW_HEIGHT_PAIRS[0],
    "brow_left": BROW_HEIGHT_PAIRS[1],
    "eye_right": LIDS_RIGHT,
    "eye_left": LIDS_LEFT,
}
EYE_MEASURES = ("eye_right", "eye_left")
BROW_COLUMNS = [list(MEASURES).index("brow_right"), list(MEASURES).index("brow_left")]  # the brows' mean
LOWPASS_HZ = 8.0
MIN_RANGE_IOD = 0.04
MIN_RANGE_EYE = 0.3
R_MIN, GAIN_MIN, GAIN_MAX = 0.9, 0.8, 1.25

# ARKit curve -> (measure it is judged against, sign of the expected correlation, r goal).
# Brow height is the mean of both brows; eye opening falls as the blink rises. Judged from
# the actor's rest, one-sided as the curves are (ClipFidelity._arkit_figures); browInnerUp
# only where the brows rise: their raise reaches 0.04 IOD on d6, d11, d12 and 0.01-0.03 on
# the others (as WRINKLE_CHECKS judges the forehead).
ARKIT_BROW_JUDGED = 0.04
ARKIT_CHECKS: dict[str, tuple[str, float, float]] = {
    "jawOpen": ("mouth_open", 1.0, 0.9),
    "eyeBlinkLeft": ("eye_left", -1.0, 0.9),
    "eyeBlinkRight": ("eye_right", -1.0, 0.9),
    "browInnerUp": ("brow", 1.0, 0.8),
}

# Gaze: name -> (eye, angle, score pair (plus, minus) whose difference it should follow):
# yaw_right, yaw_left, pitch_right, pitch_left.
GAZE_CHECKS: dict[str, tuple[int, int, tuple[str, str]]] = {
    f"{('yaw', 'pitch')[angle]}_{('right', 'left')[eye]}": (eye, angle, pair)
    for (eye, angle), pair in GAZE_SCORES.items()
}
MIN_GAZE_STD = 0.1  # std of the score difference below which the gaze barely moves
GAZE_R_GOAL = 0.8


# Landmark check of a character whose landmarks were found automatically: measure ->
# (ARKit morph, its landmark pair's change at weight 1). "open": the distance grows by at
# least the share of the inter-ocular distance; "close": it shrinks to at most the share of
# its rest value.
LANDMARK_CHECKS: dict[str, tuple[str, str, float]] = {
    "mouth_open": ("jawOpen", "open", 0.15),
    "eye_left": ("eyeBlinkLeft", "close", 0.5),
    "eye_right": ("eyeBlinkRight", "close", 0.5),
}


def landmark_faults(rig) -> dict[str, str]:
    """{measure: why} for each pair of :data:`MEASURES` that does not move the way its morph
    says (:data:`LANDMARK_CHECKS`) on a rig whose landmarks were cast automatically
    (``landmark_faces``): the landmarks are on the wrong parts of the face, the measure
    says nothing of the performance. A character without ARKit names is checked with the
    morphs the same curve drives (Godette's ``A`` + ``O``, ``Blink_L``). Rigs with hand-set
    landmarks, and morphs the rig does not have, are not checked."""
    if getattr(rig, "landmark_faces", None) is None:
        return {}
    morph = {a: m for m, a in arkit_morphs(rig.morph_names).items()}
    rest = landmark_points(rig, rig.vertices.astype(np.float64))
    iod = float(np.linalg.norm(rest[IOD_PAIR[0]] - rest[IOD_PAIR[1]]))
    _, _, have = landmark_support(rig)
    out = {}
    for name, (morph_name, way, share) in LANDMARK_CHECKS.items():
        a, b = MEASURES[name]
        if not (have[a] and have[b]):
            out[name] = f"landmarks {a}-{b} have no place on the face"
            continue
        delta = _check_delta(rig, morph, morph_name)
        if delta is None:
            continue
        moved = landmark_points(rig, rig.vertices + delta, [a, b])
        d0, d1 = float(np.linalg.norm(rest[a] - rest[b])), float(np.linalg.norm(moved[0] - moved[1]))
        if way == "open" and d1 - d0 < share * iod:
            out[name] = (f"{morph_name} opens landmarks {a}-{b} by {(d1 - d0) / max(iod, 1e-9):.2f} of the "
                         f"inter-ocular distance (at least {share:.2f} expected)")
        elif way == "close" and d1 > share * d0:
            out[name] = (f"{morph_name} closes landmarks {a}-{b} to {d1 / max(d0, 1e-9):.2f} of their rest "
                         f"distance (at most {share:.2f} expected)")
    return out


def _check_delta(rig, morph: dict[str, int], name: str) -> np.ndarray | None:
    """(V, 3) float64 what the ARKit morph ``name`` at 1 moves: its own morph, else (a
    character without ARKit names) the mix of visemes / VRM presets / Rocketbox morphs its
    curve drives; None where it has neither."""
    if name in morph:
        return rig.morph_positions[morph[name]].astype(np.float64)
    if morph:
        return None
    names = [name]
    mix = arkit_weights(names, np.ones((1, 1), np.float32), rig.morph_names)[0].astype(np.float64)
    return np.einsum("m,mvc->vc", mix, rig.morph_positions, dtype=np.float64) if mix.any() else None


# A human's reach of each measure (its morphs at 1: ICT-FaceKit's generic neutral, as
# retarget.ranges.REFERENCE_RANGE): (way, change), "up" the measure grows, "down" it shrinks,
# "either"; IOD, eyes relative to their rest opening (a blink closes them).
HUMAN_REACH: dict[str, tuple[str, float]] = {
    "mouth_open": ("up", 0.36), "mouth_width": ("either", 0.079),
    "brow_right": ("up", 0.065), "brow_left": ("up", 0.065),
    "eye_right": ("down", 1.0), "eye_left": ("down", 1.0),
}
#: A measure whose driven morphs at 1 reach less than this share of a human's is left out:
#: the character cannot make it at the actor's amplitude (Rocketbox's brow raise, 0.25).
MIN_REACH = 0.5


#: A judged IOD measure (mouth, brows) whose morphs reach less than this share of a human's is
#: judged at the head's own range: its gain against the actor's divided by that share (an anime
#: mouth opens 0.55 of a human's in IOD: at its own full range it cannot reach the 0.8 gain
#: band). The eyes are already relative to each face's own opening.
OWN_RANGE_BELOW = 0.8


#: A human's motion of each measure the other way from :data:`HUMAN_REACH`'s, or as well as it,
#: read on ICT-FaceKit's generic neutral (ict-a.glb) at its morphs at 1 as :func:`reaches`
#: reads them: below the rest, the brows' lowering (0.019 and 0.017 IOD), the mouth's narrowing
#: (0.100) and the lids' closing (0.74 and 0.72 of their rest opening: ict-a's blink leaves the
#: 3-D lid pair a quarter apart); above it, the lids' opening (eyeWide: 0.27 and 0.26). A head
#: short of one of these under :data:`OWN_RANGE_BELOW` is judged at its own range that way
#: (:meth:`ClipFidelity._own_range_source`): an anime head's presets widen its mouth but
#: cannot narrow it (0.003), and no preset opens its lids past their rest.
HUMAN_BELOW: dict[str, float] = {"brow_right": 0.018, "brow_left": 0.018, "mouth_width": 0.100,
                                 "eye_right": 0.73, "eye_left": 0.73}
HUMAN_ABOVE: dict[str, float] = {"eye_right": 0.26, "eye_left": 0.26}
#: What the figures call each measure's motion below / above its rest (``<way>_reach``).
BELOW_WAY = {"brow_right": "lowering", "brow_left": "lowering", "mouth_width": "narrowing",
             "eye_right": "closing", "eye_left": "closing"}
ABOVE_WAY = {"eye_right": "opening", "eye_left": "opening"}


def measure_reach(rig) -> dict[str, float]:
    """{measure: the share of a human's reach (:data:`HUMAN_REACH`)} that the morphs its
    landmarks solve (:func:`~capture2face.rig.arkit_names.solved_morphs`) make, each at 1 or,
    on a head of another convention, at each ARKit curve's recipe at 1 (a head with landmarks
    placed from its morphs: its recipes alone). Empty where not checked: rigs with face bones
    (which move the face without morphs) and rigs without landmarks."""
    return reaches(rig)[0]


def lowering_reach(rig) -> dict[str, float]:
    """{measure: the share of a human's motion below its rest (:data:`HUMAN_BELOW`)} its
    solved morphs make at 1, as :func:`measure_reach`: a Ready Player Me head's ``browDown``
    lowers its inner brow (landmarks 107, 336) 0.06 IOD but its mid brow (105, 334, the
    measure's) 0.002, where a human's lowers both 0.02; Godette's presets narrow its mouth
    0.003 IOD. Empty where :func:`measure_reach` is."""
    return reaches(rig)[1]


def opening_reach(rig) -> dict[str, float]:
    """{eye measure: the share of a human's opening past rest (:data:`HUMAN_ABOVE`)} its
    solved morphs make at 1, as :func:`lowering_reach`."""
    return reaches(rig)[2]


def reaches(rig) -> tuple[dict[str, float], dict[str, float], dict[str, float]]:
    """(:func:`measure_reach`, :func:`lowering_reach`, :func:`opening_reach`) of ``rig``, its
    morphs posed once."""
    change = _reach_changes(rig)
    if change is None:
        return {}, {}, {}
    reach = {}
    for k, (name, (way, human)) in enumerate(HUMAN_REACH.items()):
        most = {"up": change[:, k].max(), "down": -change[:, k].min(), "either": np.abs(change[:, k]).max()}[way]
        reach[name] = max(float(most), 0.0) / human
    names = list(MEASURES)
    below = {name: max(float(-change[:, names.index(name)].min()), 0.0) / human for name, human in HUMAN_BELOW.items()}
    above = {name: max(float(change[:, names.index(name)].max()), 0.0) / human for name, human in HUMAN_ABOVE.items()}
    return reach, below, above


def _reach_changes(rig) -> np.ndarray | None:
    """(P, 6) the :data:`MEASURES`' change from rest at each pose :func:`measure_reach`
    reads, or None where it reads none."""
    if getattr(rig, "landmark_faces", None) is None or drive_mode(rig) != "arkit":
        return None
    poses = np.eye(rig.n_morphs, dtype=np.float32)[sorted(solved_morphs(rig))]
    if not arkit_morphs(rig.morph_names):
        poses = np.concatenate([poses, recipe_poses(rig.morph_names)])
    if not len(poses):
        return None
    rest = _rest_distances(rig)
    moved = _distances(rig_landmark_points(rig, np.broadcast_to(rig.bone_rest, (len(poses),) + rig.bone_rest.shape),
                                           poses, MEASURED))
    return _normalise(moved, rest) - _normalise(rest[None], rest)


def reach_faults(rig, reach: dict[str, float] | None = None) -> dict[str, str]:
    """{measure: why} for each of :data:`MEASURES` whose :func:`measure_reach` is under
    :data:`MIN_REACH`: a visemes-only head's brows and eyes, a head with tiny brow morphs,
    an anime head whose brows no expression moves."""
    reach = measure_reach(rig) if reach is None else reach
    out = {}
    for name, share in reach.items():
        if share < MIN_REACH:
            (a, b), (way, human) = MEASURES[name], HUMAN_REACH[name]
            out[name] = (f"its morphs at 1 move landmarks {a}-{b} {way} by {share * human:.3f} at most, "
                         f"{share:.2f} of a human's {human:.3f}")
    return out


# ---- measures ----------------------------------------------------------------------------
# The landmarks the measures use, and where each pair (and the IOD pair) sits among them.
MEASURED = sorted({i for pair in MEASURES.values() for i in pair} | set(IOD_PAIR))
_PAIRS = np.array([[MEASURED.index(a), MEASURED.index(b)] for a, b in [*MEASURES.values(), IOD_PAIR]])
CHUNK = 128  # frames per block: temporaries stay small (~8 MB) whatever the clip's length


def _distances(points: np.ndarray) -> np.ndarray:
    """(F, 7) the measured pairs' distances and the IOD of (F, len(MEASURED), 3) points."""
    return np.linalg.norm(points[:, _PAIRS[:, 0]] - points[:, _PAIRS[:, 1]], axis=-1)


def _normalise(dist: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """(F, 6) measures from (F, 7) distances and the neutral's (7,): IOD units, eyes
    relative to their own neutral opening."""
    scale = np.array([neutral[k] if name in EYE_MEASURES else neutral[-1] for k, name in enumerate(MEASURES)])
    return dist[:, :-1] / np.maximum(scale, 1e-9)


def measures_from_points(points: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """(F, 6) the :data:`MEASURES` of landmark points.

    Args:
        points: (F, L, 3) landmarks (or the rig's landmark vertices, indexed by landmark).
        neutral: (L, 3) the same face at its neutral: sets the IOD and the eyes' scale.
    """
    pts = np.asarray(points, np.float64)[:, MEASURED]
    ref = np.asarray(neutral, np.float64)[None, MEASURED]
    return _normalise(_distances(pts), _distances(ref)[0])


def lowpass(x: np.ndarray, fps: float, cutoff_hz: float = LOWPASS_HZ) -> np.ndarray:
    """Zero-phase low-pass of ``x`` (F, ...) along frames: the response of a 2nd-order
    Butterworth run forward and backward, ``1 / (1 + (f / cutoff)^4)``, applied in the
    frequency domain over an odd-reflected padding of one second (as filtfilt pads; NumPy
    only: scipy.signal costs a run more than a second to import)."""
    x = np.asarray(x, np.float64)
    if fps <= 2.0 * cutoff_hz or len(x) < 16:
        return x.copy()
    pad = min(len(x) - 1, int(round(fps)))
    widths = [(pad, pad)] + [(0, 0)] * (x.ndim - 1)
    padded = np.pad(x, widths, mode="reflect", reflect_type="odd")
    freq = np.fft.rfftfreq(len(padded), 1.0 / fps)
    response = (1.0 / (1.0 + (freq / cutoff_hz) ** 4)).reshape((-1,) + (1,) * (x.ndim - 1))
    out = np.fft.irfft(np.fft.rfft(padded, axis=0) * response, n=len(padded), axis=0)
    return out[pad:pad + len(x)]


def raw_head_landmarks(track, start: int = 0, stop: int | None = None) -> np.ndarray:
    """(F, L, 3) the tracker's unfiltered landmarks in head coordinates (cm) of frames
    ``start:stop``, from the track's raw pixel landmarks and depths, posed by MediaPipe's
    own geometry."""
    stop = track.n_frames if stop is None else stop
    px = np.asarray(track.landmarks_px[start:stop], np.float64)
    depth = np.asarray(track.landmarks_depth[start:stop], np.float64)
    norm = np.concatenate([px / np.array([track.width, track.height]), depth[..., None] / track.width], -1)
    return head_landmarks(norm, track.width, track.height)[0]


def source_measures(track) -> np.ndarray:
    """(F, 6) the actor's measures: raw landmarks, head rotation removed, 8 Hz low-pass;
    IOD and eye openings of the actor's rest (:func:`~capture2face.tracking.rest.actor_rest`)
    (computed :data:`CHUNK` frames at a time: memory stays flat on long clips)."""
    n = track.n_frames
    dist = np.concatenate([_distances(raw_head_landmarks(track, s, min(n, s + CHUNK))[:, MEASURED])
                           for s in range(0, n, CHUNK)])
    rest = _distances(actor_rest(track).face[None, MEASURED].astype(np.float64))[0]
    return lowpass(_normalise(dist, rest), track.fps)


def rig_landmark_points(rig, bone_positions: np.ndarray, blend_weights: np.ndarray,
                        landmarks=None) -> np.ndarray:
    """(F, L, 3) the rig's landmark points deformed (morphs, then skinning; on their
    triangles where the rig has ``landmark_faces``); landmarks without a place stay 0. With
    ``landmarks`` (K,), only those: (F, K, 3).

    Args:
        bone_positions: (F, B, 3); blend_weights: (F, M).
    """
    support, bary, have = landmark_support(rig, landmarks)
    rows = np.flatnonzero(have)
    # Only the vertices under the landmarks are deformed.
    verts, local = np.unique(support[rows], return_inverse=True)
    local = local.reshape(len(rows), 3)
    weights = np.asarray(blend_weights, np.float64)
    pos = rig.vertices[verts].astype(np.float64) + np.einsum(
        "fm,mvc->fvc", weights, rig.morph_positions[:, verts].astype(np.float64))
    skin = rig.dense_skin_weights()[verts].astype(np.float64)  # (n, B)
    pos += np.einsum("vb,fbc->fvc", skin, np.asarray(bone_positions, np.float64) - rig.bone_rest)
    out = np.zeros((len(pos), len(have), 3))
    out[:, rows] = np.einsum("fkjc,kj->fkc", pos[:, local], bary[rows])  # a vertex: weights (1, 0, 0)
    return out


def character_measures(rig, bone_positions: np.ndarray, blend_weights: np.ndarray) -> np.ndarray:
    """(F, 6) the character's measures (its own rest pose is its neutral)."""
    if np.any(np.asarray(rig.landmark_vertices)[MEASURED] < 0):
        raise CaptureError(f"character '{rig.name}' has no vertex for some measured landmarks")
    rest = _rest_distances(rig)
    n = len(bone_positions)
    dist = np.concatenate([
        _distances(rig_landmark_points(rig, bone_positions[s:s + CHUNK], blend_weights[s:s + CHUNK], MEASURED))
        for s in range(0, n, CHUNK)])
    return _normalise(dist, rest)


def character_rest_measures(rig) -> np.ndarray:
    """(6,) the character's measures at its own rest (eyes 1 by definition)."""
    rest = _rest_distances(rig)
    return _normalise(rest[None], rest)[0]


def _rest_distances(rig) -> np.ndarray:
    """(7,) the measured pairs' distances and the IOD of the rig at rest."""
    return _distances(rig_landmark_points(rig, rig.bone_rest[None], np.zeros((1, rig.n_morphs)), MEASURED))[0]


def direct_weights(rig, scores: np.ndarray, names: list[str]) -> np.ndarray:
    """(F, M) the rig's morphs driven by the tracker's scores of the same ARKit name (any
    spelling: ``eyeBlink_L`` takes ``eyeBlinkLeft``)."""
    return arkit_weights(list(names), np.asarray(scores, np.float32), rig.morph_names)


# ---- levels and wrinkles -----------------------------------------------------------------
# The actor's rest per region: the frames whose scores of that region (REST_SCORES) sum
# lowest (the most relaxed REST_SHARE of the clip, at least REST_MIN_FRAMES), not the one
# neutral frame (which may hold an expression). The mouth's by jawOpen alone: the sum of all
# mouth scores took smiles and pouts with the lips apart (0.10 IOD on d11).
BROW_DOWN = ("browDownLeft", "browDownRight")
REST_SCORES = {"brows": ("browInnerUp", "browOuterUpLeft", "browOuterUpRight", *BROW_DOWN), "mouth": ("jawOpen",)}
REST_SHARE, REST_MIN_FRAMES = 0.1, 3
# Levels: region -> measure ("brow": both brows' mean). At the actor's rest frames the
# character's level above its own rest should match the actor's above its rest: 0 for the
# brows (their rest is those frames), the lip gap itself for the mouth (closed lips are its
# rest for everyone). Within LEVEL_TOL IOD (the goal for each region's rest).
LEVEL_CHECKS = {"brows": "brow", "mouth": "mouth_open"}
LEVEL_TOL = 0.01
# Wrinkles: (check, the motion it follows, the motion's 99th percentile from which it is
# judged (IOD)), in the order of ClipFidelity.wrinkles' columns. On the shared clips the brows
# rise 0.08-0.10 IOD above rest where browInnerUp reaches 0.86-1.0 (d6, d11, d12) and at most
# 0.03 where it stays below 0.3 (d0, d3, d18): 0.04 splits them as the issue's "browInnerUp
# moves by 0.3" does. They lower 0.05 IOD on d3 (browDown 0.89) and at most 0.01 on the clips
# whose browDown stays below 0.3 (noise); d18 (browDown 0.7) lowers 0.014 at these landmarks
# (its frown draws the inner brows together more than down): 0.02 judges d3 only, not noise.
WRINKLE_REGIONS = (("forehead", "stretch"), ("glabella", "compress"))
WRINKLE_CHECKS = (("forehead_stretch", "brow_raise", 0.04), ("glabella_compress", "brow_lowering", 0.02))
WRINKLE_R_GOAL = 0.8
# Where browDown stays below NEVER_LOWER_SCORE throughout, the glabella should not fold:
# compress's 99th percentile below AT_REST_P99_GOAL (issue 21's goals).
NEVER_LOWER_SCORE, AT_REST_P99_GOAL = 0.1, 0.15


def rest_frames(scores: np.ndarray, names: list[str], region: str) -> np.ndarray:
    """(K,) the frames where a region is most relaxed: the lowest :data:`REST_SHARE` of its
    scores' sum (at least :data:`REST_MIN_FRAMES`); all frames without such scores.

    Args:
        scores: (T, S) the tracker's scores, names in ``names``.
    """
    cols = [k for k, n in enumerate(names) if n in REST_SCORES[region]]
    n = len(scores)
    if not cols or n == 0:
        return np.arange(n)
    k = min(n, max(REST_MIN_FRAMES, round(REST_SHARE * n)))
    return np.sort(np.argsort(np.asarray(scores, np.float64)[:, cols].sum(1), kind="stable")[:k])


def wrinkle_series(animation) -> np.ndarray | None:
    """(F, 2) the animation's region influences of :data:`WRINKLE_REGIONS`, or None when it
    has not those regions or poses."""
    regions, poses = list(getattr(animation, "region_names", [])), list(getattr(animation, "pose_names", []))
    infl = getattr(animation, "region_influence", None)
    if infl is None or any(r not in regions or p not in poses for r, p in WRINKLE_REGIONS):
        return None
    infl = np.asarray(infl, np.float64)
    return np.stack([infl[:, regions.index(r), poses.index(p)] for r, p in WRINKLE_REGIONS], 1)


# ---- figures -----------------------------------------------------------------------------
def compare(source: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """(r, gain) of one measure over frames."""
    s_std = float(np.std(source))
    return pearson(source, other), (float(np.std(other)) / s_std if s_std > 1e-12 else 0.0)


def faithful(r: float, gain: float) -> bool:
    return r >= R_MIN and GAIN_MIN <= gain <= GAIN_MAX


def not_worse(r: float, gain: float, other_r: float, other_gain: float) -> bool:
    """r at least as high as the other drive's, or a gain at least as close to 1 (in log
    terms): worse means behind it on both."""
    return bool(r >= other_r - 1e-3 or abs(np.log(max(gain, 1e-6))) <= abs(np.log(max(other_gain, 1e-6))))


@dataclass
class ClipFidelity:
    """One clip's measures over its tracked frames (T of them).

    Attributes:
        name: clip name.
        times: (T,) seconds.
        source, character, direct: (T, 6) the measures (see module doc).
        curves: (T, 6) the character driven by the animation's ARKit curves alone (its
            ARKit-named morphs, bones at rest): what the retargeting must not be worse
            than; None without curves or ARKit-named morphs.
        arkit: (T, A) ARKit curves judged, names in ``arkit_names``.
        arkit_source: which curves were judged ("animation" or "tracker").
        gaze: (T, 2, 2) the animation's eye yaw and pitch (degrees), or None.
        gaze_scores: (T, 4) the tracker's score differences of :data:`GAZE_CHECKS`.
        left_out: {measure: why} measures left out of the figures: the character's landmark
            pair does not move with its morph (:func:`landmark_faults`), or its morphs reach
            under half a human's (:func:`reach_faults`).
        reach: {measure: share of a human's reach} (:func:`measure_reach`): a mouth or brow
            measure under :data:`OWN_RANGE_BELOW` is judged at the head's own range
            (``range_gain``); empty: every measure judged at the actor's amplitude.
        lowering: {measure: share of a human's motion below its rest} (:func:`lowering_reach`:
            the brows' lowering, the mouth's narrowing, the lids' closing): one under
            :data:`OWN_RANGE_BELOW` is judged against the actor's motion at the head's own
            range, its motion below the actor's rest (``source_rest``) scaled by it
            (``range_r``, ``range_gain``).
        opening: {eye measure: share of a human's opening past rest} (:func:`opening_reach`):
            one under :data:`OWN_RANGE_BELOW` scales the actor's motion above its rest so.
        scores: (T, S) the tracker's scores, names in ``score_names``: which frames are the
            actor's rest (:func:`rest_frames`), whether the brows ever lower; None: no
            level or wrinkle checks.
        character_rest: (6,) the character's measures at its own rest (levels), or None.
        source_rest: (6,) the actor's measures at its rest (each region's rest frames, as
            the ARKit curves are calibrated), or None.
        wrinkles: (T, 2) the animation's forehead "stretch" and glabella "compress" region
            influences (:data:`WRINKLE_REGIONS`), or None (no wrinkle checks).
    """

    name: str
    times: np.ndarray
    source: np.ndarray
    character: np.ndarray
    direct: np.ndarray
    arkit: np.ndarray
    arkit_names: list[str]
    arkit_source: str
    gaze: np.ndarray | None = None
    gaze_scores: np.ndarray | None = None
    curves: np.ndarray | None = None
    left_out: dict[str, str] = field(default_factory=dict)
    scores: np.ndarray | None = None
    score_names: list[str] = field(default_factory=list)
    character_rest: np.ndarray | None = None
    wrinkles: np.ndarray | None = None
    source_rest: np.ndarray | None = None
    reach: dict[str, float] = field(default_factory=dict)
    lowering: dict[str, float] = field(default_factory=dict)
    opening: dict[str, float] = field(default_factory=dict)

    def figures(self) -> dict:
        """Per measure r, gain, source range, judged and faithful for the character and
        the direct alternative (and the curves-only drive); ARKit curve correlations; a
        summary."""
        out: dict = {"clip": self.name, "frames": int(len(self.times)), "measures": {}, "arkit": {}}
        if self.left_out:
            out["left_out"] = dict(self.left_out)
        out["measures"], out["summary"] = self._measure_figures()
        out["arkit"] = self._arkit_figures()
        out["arkit_source"] = self.arkit_source
        if self.gaze is not None and self.gaze_scores is not None:
            out["gaze"] = {}
            for k, (name, (eye, angle, _)) in enumerate(GAZE_CHECKS.items()):
                score = self.gaze_scores[:, k]
                spread = float(score.std()) if len(score) else 0.0
                r = pearson(self.gaze[:, eye, angle], score)
                entry = {"r": round(r, 3), "score_std": round(spread, 3),
                         "judged": bool(name.startswith("yaw") and spread >= MIN_GAZE_STD)}
                if entry["judged"]:
                    entry.update(goal=GAZE_R_GOAL, met=bool(r >= GAZE_R_GOAL))
                out["gaze"][name] = entry
        if self.scores is not None and self.character_rest is not None:
            out["levels"] = self._level_figures()
        if self.scores is not None and self.wrinkles is not None:
            out["wrinkles"] = self._wrinkle_figures()
        return out

    def _arkit_figures(self) -> dict:
        """Each :data:`ARKIT_CHECKS` curve's r with its geometry, one-sided from the actor's
        rest as the curve is (a frown is browDown, not a negative browInnerUp; eyes wider
        than at rest are eyeWide): ``max(sign * (measure - rest), 0)`` with ``source_rest``;
        signed without it. browInnerUp is judged where the brows rise
        :data:`ARKIT_BROW_JUDGED` above rest (99th percentile)."""
        out = {}
        for name, (measure, sign, goal) in ARKIT_CHECKS.items():
            if name not in self.arkit_names:
                continue
            cols = BROW_COLUMNS if measure == "brow" else [list(MEASURES).index(measure)]
            geo = sign * self.source[:, cols].mean(1)
            judged = True
            if self.source_rest is not None:
                geo = np.maximum(geo - sign * float(np.mean(self.source_rest[cols])), 0.0)
                judged = measure != "brow" or float(np.percentile(geo, 99)) >= ARKIT_BROW_JUDGED
            curve = self.arkit[:, self.arkit_names.index(name)]
            r = pearson(geo, curve)
            out[name] = {"against": measure, "r": round(r, 3), "goal": goal, "max": round(float(curve.max()), 3),
                         "judged": judged, "met": bool(judged and r >= goal)}
        return out

    def brow(self) -> np.ndarray:
        """(T,) the actor's brow height (mean of both brows, IOD)."""
        return self.source[:, BROW_COLUMNS].mean(1)

    def brow_motion(self) -> tuple[np.ndarray, np.ndarray, float]:
        """(raise (T,), lowering (T,), rest): the actor's brows above and below their rest
        height (IOD, each one-sided as the wrinkles are)."""
        brow = self.brow()
        rest = float(np.median(brow[rest_frames(self.scores, self.score_names, "brows")]))
        return np.maximum(brow - rest, 0.0), np.maximum(rest - brow, 0.0), rest

    def _level_figures(self) -> dict:
        """Brows and mouth (:data:`LEVEL_CHECKS`): the character's level above its own rest
        at the actor's rest frames (``character_level``), the actor's (``actor_level``), and
        their difference (``offset``, IOD)."""
        out = {}
        for region, measure in LEVEL_CHECKS.items():
            at = rest_frames(self.scores, self.score_names, region)
            if measure == "brow":
                actor, ks = self.brow(), BROW_COLUMNS
            else:
                actor, ks = self.source[:, list(MEASURES).index(measure)], [list(MEASURES).index(measure)]
            character = float(np.median(self.character[at][:, ks].mean(1))) - float(np.mean(self.character_rest[ks]))
            actor_level = 0.0 if measure == "brow" else float(np.median(actor[at]))
            offset = character - actor_level
            out[region] = {"measure": measure, "rest_frames": len(at),
                           "actor_rest": round(float(np.median(actor[at])), 4),
                           "character_level": round(character, 4), "actor_level": round(actor_level, 4),
                           "offset": round(offset, 4), "tolerance": LEVEL_TOL,
                           "met": bool(abs(offset) <= LEVEL_TOL)}
        return out

    def _wrinkle_figures(self) -> dict:
        """Forehead stretch against brow raise, glabella compress against brow lowering
        (r where the brows move enough), glabella compress where the brows never lower."""
        rise, lower, rest = self.brow_motion()
        out: dict = {"brow_rest": round(rest, 4)}
        for k, ((name, motion, judged_at), series) in enumerate(zip(WRINKLE_CHECKS, (rise, lower))):
            amount = float(np.percentile(series, 99)) if len(series) else 0.0
            r = pearson(self.wrinkles[:, k], series)
            entry = {"against": motion, "amount": round(amount, 4), "judged": bool(amount >= judged_at),
                     "r": round(r, 3)}
            if entry["judged"]:
                entry.update(goal=WRINKLE_R_GOAL, met=bool(r >= WRINKLE_R_GOAL))
            out[name] = entry
        cols = [self.score_names.index(n) for n in BROW_DOWN if n in self.score_names]
        down = float(self.scores[:, cols].max()) if cols and len(self.scores) else 1.0
        p99 = float(np.percentile(self.wrinkles[:, 1], 99)) if len(self.wrinkles) else 0.0
        entry = {"brow_down_max": round(down, 3), "judged": bool(down < NEVER_LOWER_SCORE), "p99": round(p99, 3)}
        if entry["judged"]:
            entry.update(goal=AT_REST_P99_GOAL, met=bool(p99 < AT_REST_P99_GOAL))
        out["glabella_unfrowned"] = entry
        checks = [e for e in out.values() if isinstance(e, dict) and e["judged"]]
        out["judged"], out["met"] = len(checks), sum(e["met"] for e in checks)
        return out

    def _measure_figures(self) -> tuple[dict, dict]:
        measures: dict = {}
        counts = {"judged": 0, "faithful": 0, "not_worse_than_direct": 0}
        if self.curves is not None:
            counts["not_worse_than_curves"] = 0
        for k, name in enumerate(MEASURES):
            if name in self.left_out:  # the character's landmarks for it do not move with its morph
                continue
            src = self.source[:, k]
            rng = float(src.max() - src.min()) if len(src) else 0.0
            limit = MIN_RANGE_EYE if name in EYE_MEASURES else MIN_RANGE_IOD
            r, g = compare(src, self.character[:, k])
            dr, dg = compare(src, self.direct[:, k])
            entry = {"range": round(rng, 4), "judged": rng >= limit, "r": round(r, 3), "gain": round(g, 3)}
            share = 1.0 if name in EYE_MEASURES else self.reach.get(name, 1.0)
            scale = 1.0 / share if share < OWN_RANGE_BELOW else 1.0  # judged at the head's own range
            own = self._own_range_source(k, name, share)
            if own is not None:  # a head short of a human's motion below its rest (or past it): at its own range
                src, scale, ways = own[0], 1.0, own[1]
                r, g = compare(src, self.character[:, k])
                dr, dg = compare(src, self.direct[:, k])
                entry.update({key: round(v, 3) for key, v in ways.items()})
                entry.update(range_r=round(r, 3), range_gain=round(g, 3))
            elif scale != 1.0:
                entry.update(reach=round(share, 3), range_gain=round(g * scale, 3))
            entry.update(faithful=faithful(r, g * scale), direct_r=round(dr, 3), direct_gain=round(dg, 3),
                         direct_faithful=faithful(dr, dg * scale))
            if self.curves is not None:
                cr, cg = compare(src, self.curves[:, k])
                entry.update(curves_r=round(cr, 3), curves_gain=round(cg, 3), curves_faithful=faithful(cr, cg * scale))
            measures[name] = entry
            if entry["judged"]:
                counts["judged"] += 1
                counts["faithful"] += entry["faithful"]
                counts["not_worse_than_direct"] += not_worse(r, g * scale, dr, dg * scale)
                if self.curves is not None:
                    counts["not_worse_than_curves"] += not_worse(r, g * scale, cr, cg * scale)
        return measures, counts

    def _own_range_source(self, k: int, name: str, share: float) -> tuple[np.ndarray, dict] | None:
        """((T,) the actor's measure ``k`` at the head's own range, {way: share} of the ways
        short) where the head moves it below its rest under :data:`OWN_RANGE_BELOW` of a
        human's, or (the eyes) past its rest: the actor's motion below its rest times that
        share, above it times the share that way (the raise's, the lids' opening) where also
        under; None elsewhere. A head short only its main way (an anime mouth's opening) is
        judged by its gain over that share (:meth:`_measure_figures`): the same where the
        actor moves only that way."""
        down = self.lowering.get(name, 1.0)
        up = self.opening.get(name, 1.0) if name in EYE_MEASURES else share
        short_up = up < OWN_RANGE_BELOW and name in EYE_MEASURES  # other measures' raise alone: by its gain
        if self.source_rest is None or not (down < OWN_RANGE_BELOW or short_up):
            return None
        up, down = (u if u < OWN_RANGE_BELOW else 1.0 for u in (up, down))
        ways = {"reach" if name not in EYE_MEASURES else f"{ABOVE_WAY[name]}_reach": up} if up < 1.0 else {}
        if down < 1.0:
            ways[f"{BELOW_WAY[name]}_reach"] = down
        d = self.source[:, k] - self.source_rest[k]
        return self.source_rest[k] + up * np.maximum(d, 0.0) + down * np.minimum(d, 0.0), ways


def clip_fidelity(track, animation, rig, name: str = "") -> ClipFidelity:
    """The measures of one retargeted clip (its ``Track``, ``Animation`` and character)."""
    keep = np.asarray(track.presence, bool)
    reach, lowering, opening = reaches(rig)
    source = source_measures(track)
    character = character_measures(rig, animation.bone_positions, animation.blend_weights)
    scores = np.asarray(track.blendshapes)
    rest = np.broadcast_to(rig.bone_rest[None], (len(scores),) + rig.bone_rest.shape)  # a view, no copy
    direct = character_measures(rig, rest, direct_weights(rig, scores, track.blendshape_names))
    curves = None
    if getattr(animation, "arkit_weights", None) is not None:
        arkit, names, which = np.asarray(animation.arkit_weights), list(animation.arkit_names), "animation"
        if arkit_morphs(rig.morph_names):
            curves = character_measures(rig, rest, arkit_weights(names, arkit, rig.morph_names))[keep]
    else:
        arkit, names, which = scores, list(track.blendshape_names), "tracker"
    gaze = gaze_scores = None
    if getattr(animation, "eye_rotation", None) is not None:
        col = {n: i for i, n in enumerate(track.blendshape_names)}
        if all(a in col and b in col for _, _, (a, b) in GAZE_CHECKS.values()):
            gaze = np.asarray(animation.eye_rotation, np.float64)[keep]
            gaze_scores = np.stack([scores[:, col[a]].astype(np.float64) - scores[:, col[b]]
                                    for _, _, (a, b) in GAZE_CHECKS.values()], 1)[keep]
    return ClipFidelity(name=name or Path(str(track.source)).stem, times=np.asarray(track.times)[keep],
                        source=source[keep], character=character[keep], direct=direct[keep],
                        arkit=np.asarray(arkit[keep], np.float64), arkit_names=names, arkit_source=which,
                        gaze=gaze, gaze_scores=gaze_scores, curves=curves,
                        left_out={**reach_faults(rig, reach), **landmark_faults(rig)}, reach=reach,
                        lowering=lowering, opening=opening,
                        scores=scores[keep].astype(np.float64), score_names=list(track.blendshape_names),
                        character_rest=character_rest_measures(rig), wrinkles=_kept(wrinkle_series(animation), keep),
                        source_rest=source_rest_measures(track, source))


def source_rest_measures(track, source: np.ndarray) -> np.ndarray:
    """(6,) the actor's measures at rest: each measure's median over its region's rest
    frames (the brows', the eyes', the mouth's), or of the rest's landmarks for a rest from
    outside the clip. ``source``: (F, 6) :func:`source_measures`."""
    rest = actor_rest(track)
    out = measures_from_points(rest.landmarks[None].astype(np.float64), rest.face.astype(np.float64))[0]
    region = {"mouth_open": "mouth", "mouth_width": "mouth", "brow_right": "brows", "brow_left": "brows",
              "eye_right": "eyes", "eye_left": "eyes"}
    for k, name in enumerate(MEASURES):
        frames = np.asarray(rest.frames.get(region[name], ()), np.int64)
        if len(frames):
            out[k] = np.median(source[frames, k])
    return out


def _kept(values: np.ndarray | None, keep: np.ndarray) -> np.ndarray | None:
    return None if values is None else values[keep]

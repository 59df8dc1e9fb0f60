"""ARKit curves with ARKit meaning, from a :class:`~capture2face.tracking.track.Track`.

MediaPipe's blendshape scores are ARKit-named but not ARKit-scaled: at a real clip's
neutral they rest above 0 (jawOpen 0.3 on some clips), a fully open jaw or a closed eye
often scores 0.6-0.8, and browInnerUp barely follows the brows. :func:`arkit_curves`
gives each of the 52 curves ARKit's meaning (0 at rest, 1 at the full pose):

* **every curve**: the score calibrated to the clip's rest, ``(s - s0) / (1 - s0)``
  clipped to [0, 1], ``s0`` the score at the actor's rest (its region's, :mod:`capture2face.tracking.rest`).
  Subtracting alone would cap the curve at ``1 - s0``; dividing by ``1 - s0`` keeps a
  saturated score at 1, so the full range survives while the rest lands on 0.
* **jawOpen, eyeBlinkLeft/Right, browInnerUp** (:data:`GEOMETRIC`): the curve is the
  face's geometry instead, per clip mapped to [0, 1]: mouth opening 13-14, eye closure
  1 - opening / rest opening (159-145, 386-374), brow height 105-33 / 334-263. The
  tracker's landmark filter (One Euro, :data:`LANDMARK_FILTER`) takes part of the fast
  motion of blinks and jaw snaps away, so the detail it removed is put back from the score (the score
  mapped to centimetres by a per-clip fit, minus the same filter's output on it): the
  slow part comes from the geometry, the fast part from the score. The gain from
  geometry to curve is fitted per clip to the calibrated score, but never below an
  anatomical full range (:data:`FULL_RANGE`): MediaPipe's scores are compressed, so the
  fit alone would leave a wide-open jaw at 0.5. Lids also lower when the eyes look down or
  squint, which ARKit calls eyeLookDown and eyeSquint: where the blink score stays within
  :data:`BLINK_GATE` of its rest, the closure fades out with it.
* **a calibrated actor** (a track carrying a calibration from a range-of-motion take,
  :mod:`capture2face.calibration`): each curve the take showed is the calibration's: the
  curve above with the take's gain and offset where the tracker read it well on the take
  (jawOpen's lip gap averaged with its score, each on the take's line: they err on
  different expressions), else this actor's own expressions mixed to fit the frame; the
  others as above. A calibration of several takes reads the clip once per take and the
  curves are the mean.
* then all curves pass a zero-phase One Euro filter tuned for [0, 1] scores
  (:data:`SCORE_FILTER`) and are clipped to [0, 1].
"""

from __future__ import annotations

import numpy as np

from capture2face.calibration.attach import track_calibration
from capture2face.calibration.learn import (
    calibrate,
    calibrated_curves,
    calibration_rest,
    clip_weights,
    explained_away,
    scored_curves,
    tracker_adjusted,
)
from capture2face.maths.stats import pearson
from capture2face.tracking.filtering import OneEuro, one_euro
from capture2face.tracking.rest import GEOMETRY_PAIRS, ActorRest, actor_rest, pair_distances
from capture2face.tracking.tracker import TrackOptions

# curve -> landmark pairs whose distance is its geometric measure (two pairs: the mean):
# the rest's own geometry, so a curve's rest is where its region's rest was judged.
GEOMETRIC: dict[str, tuple[tuple[int, int], ...]] = {
    "jawOpen": GEOMETRY_PAIRS["lip_gap"],
    "eyeBlinkLeft": GEOMETRY_PAIRS["lid_left"],
    "eyeBlinkRight": GEOMETRY_PAIRS["lid_right"],
    "browInnerUp": GEOMETRY_PAIRS["brow_height"],
}
# The geometric measure at which a curve reads 1: jaw and brows in inter-ocular distances
# above rest, eyes as the fraction of the neutral opening closed. jawOpen: ICT-FaceKit's
# ARKit-scaled jawOpen at 1 parts the inner lips by 0.40-0.41 IOD on all its heads (3.7 cm;
# the real clips' wide-open jaws reach 0.33-0.52); eyes: its eyeBlink closes 0.66-0.74 of
# the opening (MediaPipe's mesh keeps the lids apart); brows rise ~0.7 cm.
FULL_RANGE = {"jawOpen": 0.4, "eyeBlinkLeft": 0.75, "eyeBlinkRight": 0.75, "browInnerUp": 0.08}
# The fitted gain may exceed 1 / FULL_RANGE by this factor at most (a score that saturates
# early would otherwise clip most of the motion at 1).
MAX_GAIN_FACTOR = 2.0
# Below this correlation with the geometry the score carries no trustworthy detail (e.g.
# browInnerUp on a clip whose brows hardly move).
MIN_DETAIL_R = 0.3
# Scores move 0 -> 1 in ~0.1 s in a blink (speed ~10/s): beta 5 opens the cutoff to ~50 Hz
# there, while a still score is smoothed at 1 Hz (its jitter is ~0.01).
SCORE_FILTER = OneEuro(min_cutoff=1.0, beta=5.0, d_cutoff=1.0, zero_phase=True)
FILTER_COLUMNS = 8  # curves calibrated and filtered together (memory of the temporaries)
# The tracker's landmark filter (TrackOptions defaults): what it took from the geometry is
# what the score's detail restores.
LANDMARK_FILTER = TrackOptions().landmark_filter()
# jawOpen's rest: the actor's lip gap, or the clip's 2% most closed frames where the lips
# press tighter. (Before each region had its rest, eyeBlink and browInnerUp took the clip's
# widest eyes and lowest brows too: on a synthetic ICT actor that read its neutral as a
# 0.23 blink and a 0.6 brow raise, MAE 0.25 and 0.31 against the truth's weights; from
# the eyes' and brows' rest, 0.06 and 0.03.)
REST_PERCENTILE = 2.0
# The calibrated blink score from which the lids' closure counts in full as a blink (below
# it, scaled by score / gate). On synthetic ICT actors, whose lids follow the gaze and
# squints, the eyeBlink MAE falls by a fifth; larger gates cut more there but leave the
# real clips' blinks less tied to the lids' closure (below r 0.9 on d6 and d18 from 0.2).
BLINK_GATE = 0.1


def calibrate_scores(scores: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(F, S) scores with ``rest`` (S,) mapped to 0 and 1 kept at 1, clipped to [0, 1]."""
    rest = np.clip(np.asarray(rest, np.float64), 0.0, 0.99)  # a score resting at 1 has no range left
    return np.clip((np.asarray(scores, np.float64) - rest) / (1.0 - rest), 0.0, 1.0)


def restore_detail(distance: np.ndarray, score: np.ndarray, times: np.ndarray, sign: float) -> np.ndarray:
    """(F,) ``distance`` (cm, landmark-filtered) plus the fast motion the landmark filter
    removed, taken from ``score`` (F,) mapped to cm by a least-squares fit; ``sign``: +1
    when the score rises with the distance, -1 when it falls (a blink closes the lids)."""
    if len(distance) < 3 or sign * pearson(score, distance) < MIN_DETAIL_R:
        return distance
    slope = np.polyfit(score, distance, 1)[0]
    cm = slope * score  # the score in cm: the landmark filter's speed units apply
    return distance + (cm - one_euro(cm, times, LANDMARK_FILTER))


def geometric_curves(track, rest: ActorRest, wanted: list[str]) -> dict[int, np.ndarray]:
    """Column -> (F,) the curve of each of ``wanted`` (:data:`GEOMETRIC` names) from the
    face's geometry read against ``rest``, unfiltered ({} for a track under 3 frames)."""
    names = list(track.blendshape_names)
    raw = np.asarray(track.blendshapes)
    times = np.asarray(track.times, np.float64)
    geometric = {}  # column -> its curve from the geometry (F,)
    if not wanted or len(raw) < 3:
        return geometric
    dist, _ = pair_distances(track.landmarks_head, GEOMETRIC)
    rest_dist, rest_iod = pair_distances(rest.landmarks[None], GEOMETRIC)
    iod = max(float(rest_iod[0]), 1e-6)
    for k in [k for k, name in enumerate(GEOMETRIC) if name in wanted]:
        name = list(GEOMETRIC)[k]
        c = names.index(name)
        score = np.nan_to_num(raw[:, c].astype(np.float64))
        blink = name.startswith("eyeBlink")
        d = restore_detail(dist[:, k], score, times, -1.0 if blink else 1.0)
        # Rest: the actor's (its region's). Eyes wider than at rest are eyeWide and brows
        # below it browDown, not less than 0; only lips pressed tighter than at rest
        # (the clip's most closed frames, from the filtered geometry: the restored
        # detail can overshoot a step) still read 0.
        g = dist[:, k]
        if blink:
            m = 1.0 - d / max(rest_dist[0, k], 1e-6)  # fraction of the rest opening closed
        elif name == "jawOpen":
            m = (d - min(rest_dist[0, k], np.percentile(g, REST_PERCENTILE))) / iod
        else:
            m = (d - rest_dist[0, k]) / iod
        target = calibrate_scores(score, rest.scores[c])
        up = np.clip(m, 0.0, None)
        # Per-clip gain: the calibrated score's scale, floored by the anatomical full
        # range (the scores are compressed) and capped against early saturation.
        fit = float((target * up).sum() / max((up * up).sum(), 1e-12))
        floor = 1.0 / FULL_RANGE[name]
        geometric[c] = np.clip(m * np.clip(fit, floor, MAX_GAIN_FACTOR * floor), 0.0, 1.0)
        if blink and BLINK_GATE > 0:
            geometric[c] *= np.clip(target / BLINK_GATE, 0.0, 1.0)
    return geometric


def arkit_curves(track, rest: ActorRest | None = None) -> np.ndarray:
    """(F, S) float32 ARKit curves in [0, 1], columns named and ordered as
    ``track.blendshape_names`` (MediaPipe's 52: ``_neutral`` then the ARKit names).

    Args:
        track: a Track with ``blendshapes`` (F, S) raw scores, ``landmarks_head`` (F, 478, 3)
            cm, ``times`` (F,).
        rest: the actor's rest (default: the track's, :func:`~capture2face.tracking.rest.actor_rest`).
    """
    rest = actor_rest(track) if rest is None else rest
    names = list(track.blendshape_names)
    raw = np.asarray(track.blendshapes)  # (F, S) float32: read a few columns at a time
    times = np.asarray(track.times, np.float64)
    geometric = geometric_curves(track, rest, [n for n in GEOMETRIC if n in names])

    # A few columns at a time: each curve is calibrated and filtered on its own, so this is
    # the same as the whole (F, S) at once with a fraction of the float64 temporaries.
    out = np.empty(raw.shape, np.float32)
    for c0 in range(0, raw.shape[1], FILTER_COLUMNS):
        cols = range(c0, min(c0 + FILTER_COLUMNS, raw.shape[1]))
        scores = np.nan_to_num(raw[:, c0:cols.stop].astype(np.float64))
        curves = calibrate_scores(scores, rest.scores[c0:cols.stop])
        for j, c in enumerate(cols):
            if names[c] == "_neutral":  # not an ARKit curve: MediaPipe's own "no expression" score, kept
                curves[:, j] = scores[:, j]
            elif c in geometric:
                curves[:, j] = geometric[c]
        out[:, c0:cols.stop] = np.clip(one_euro(curves, times, SCORE_FILTER), 0.0, 1.0)
    calibration = track_calibration(track)
    if calibration is None:
        return out
    # Several takes: each take's calibration reads the clip on its own; the curves are their mean.
    takes = [_take_curves(track, take, out, rest, times) for take in calibration.takes]
    return takes[0] if len(takes) == 1 else np.mean(takes, 0).astype(np.float32)


def _take_curves(track, calibration, curves: np.ndarray, rest: ActorRest, times: np.ndarray) -> np.ndarray:
    """(F, S) float32 ``curves`` (the uncalibrated, filtered ones) as one take's
    ``calibration`` reads the clip: the curves from the actor's expressions mixed and
    filtered in their place, then the tracker's kept ones adjusted and what other steps
    raise taken off."""
    names = list(track.blendshape_names)
    out = np.array(curves, np.float32, copy=True)
    weights = np.zeros((track.n_frames, 0))
    if calibration.curves:
        weights = clip_weights(track, calibration)
        mixed = calibrated_curves(track, calibration, np.zeros(out.shape, np.float32), weights=weights)
        cols = [names.index(n) for n, c in calibration.curves.items() if n in names and c["source"] == "expressions"]
        if cols:
            out[:, cols] = np.clip(one_euro(mixed[:, cols].astype(np.float64), times, SCORE_FILTER), 0.0, 1.0)
        _take_rest_geometry(out, track, calibration, times)
    out = tracker_adjusted(out, calibration, names, _calibration_scores(track, calibration, rest, times))
    return out if not calibration.curves else explained_away(out, calibration, names, weights)


def _take_rest_geometry(out: np.ndarray, track, calibration, times: np.ndarray) -> None:
    """``out`` (F, S) with each curve of source "geometry" the face's geometry read against
    the calibration's rest laid onto the clip, filtered as the others, on its gain and offset
    (in place)."""
    names = list(track.blendshape_names)
    wanted = [n for n, c in calibration.curves.items() if c["source"] == "geometry" and n in GEOMETRIC and n in names]
    if not wanted:
        return
    for c, curve in geometric_curves(track, calibration_rest(calibration, track), wanted).items():
        spec = calibration.curves[names[c]]
        filtered = np.clip(one_euro(curve, times, SCORE_FILTER), 0.0, 1.0)
        out[:, c] = np.clip(spec["gain"] * filtered + spec["offset"], 0.0, 1.0)


def _calibration_scores(track, calibration, rest: ActorRest, times: np.ndarray) -> dict[str, np.ndarray]:
    """name -> (F,) the tracker's score calibrated to the clip's rest and filtered as the
    curves are, for each curve the calibration averages with its score (jawOpen: the lip
    gap's geometry and the score err on different expressions)."""
    names = list(track.blendshape_names)
    wanted = scored_curves(calibration, names)
    if not wanted:
        return {}
    cols = [names.index(n) for n in wanted]
    scores = np.nan_to_num(np.asarray(track.blendshapes)[:, cols].astype(np.float64))
    filtered = one_euro(calibrate_scores(scores, rest.scores[cols]), times, SCORE_FILTER)
    return dict(zip(wanted, np.clip(filtered, 0.0, 1.0).T))


def calibrate_take(track):
    """The :class:`~capture2face.calibration.ActorCalibration` of a tracked ROM take
    (:func:`capture2face.calibration.calibrate`), judging the tracker's own curves as this
    module reads them."""
    return calibrate(track, base_curves=arkit_curves(track))

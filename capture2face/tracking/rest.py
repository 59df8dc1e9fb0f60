"""The actor's rest, region by region: what every later stage measures expression from.

One neutral frame for the whole face fails an actor who never relaxes everything at once
(brows raised through a clip whose mouth rests, a held smile while the brows rest): every
frame with the brows lower than that frame's reads as a frown. So the face is split into
three regions (:data:`REGIONS`: brows and forehead, eyes, mouth and jaw;
:func:`landmark_regions`), and each region takes its rest from the frames where *it* is
most relaxed, judged by its scores and its geometry together (:func:`region_costs`): the
median of those frames' head-coordinate landmarks and scores (the median also takes out
the jitter a single frame carries).

What reads it: the ARKit calibration (each score's rest, each geometric curve's rest),
the gaze (straight ahead: the eyes' rest) and the brows' wrinkles (each brow bone's
reference is its median over the brows' rest frames,
:func:`capture2face.retarget.driver.wrinkle_reference`).
The feature-point network maps one consistent face onto the character's rest: ``face``,
the median of the frames calmest over all regions together. A face assembled from each
region's own frames lies askew, because MediaPipe's fitted head pose (and so the head
coordinates) moves with the expression: the upper face shrinks as the jaw opens, and the
lids' rest taken during a grimace halved the blinks' r (docs/rest.md has the figures).

A rest can also come from one frame (``--neutral-frame``) or from outside the clip
(``--neutral-image``, ``--neutral-clip``: :func:`aligned_rest` puts it in the clip's head
coordinates).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from capture2face.io.framestore import take_points
from capture2face.maths.rotations import similarity
from capture2face.rig.canonical import load_canonical_mesh
from capture2face.topology import (
    BROW_HEIGHT_PAIRS,
    BROWS,
    CHIN,
    EYE_LEFT,
    EYE_RIGHT,
    IOD_PAIR,  # the outer eye corners: the face's size (re-exported: tracking.rest.IOD_PAIR)
    LIDS_LEFT,
    LIDS_RIGHT,
    LIP_GAP,
    LIPS_INNER,
    LIPS_OUTER,
)
from capture2face.tracking.neutral import CLOSED_GAP, STEADY_SPEED, head_speed

REGIONS = ("brows", "eyes", "mouth")
FACE = "face"  # the whole face's rest frames (ActorRest.face)
# Each region's own features on the canonical face (:func:`landmark_regions`). Brows: both
# brows' contours; eyes: the lids' contours; mouth: the lips and the chin.
_FEATURES = {
    "brows": tuple(sorted(BROWS)),
    "eyes": tuple(sorted(EYE_RIGHT + EYE_LEFT)),
    "mouth": tuple(sorted(LIPS_OUTER + LIPS_INNER)) + CHIN,
}
# The eyes' region reaches this far (cm, canonical face) from the lids: the cheeks below
# move with the mouth (a grimace lifts them 5 mm), not with the lids.
EYE_REACH_CM = 0.8
# Score names by region (MediaPipe's spelling of ARKit's): a region is relaxed when these are low.
_SCORE_PREFIXES = {"brows": ("brow",), "eyes": ("eye",), "mouth": ("mouth", "jaw", "cheek", "nose")}

# Geometry (:func:`rest_geometry`'s columns, inter-ocular distances): lip gap, brow height
# above the outer eye corners (mean of both), the lids' openings (right, left).
GEOMETRY = ("lip_gap", "brow_height", "lid_right", "lid_left")
GEOMETRY_PAIRS = {"lip_gap": (LIP_GAP,), "brow_height": BROW_HEIGHT_PAIRS,
                  "lid_right": (LIDS_RIGHT,), "lid_left": (LIDS_LEFT,)}
BROW_SCALE = 0.03  # brows this far (IOD) from their rest height cost as much
LID_SCALE = 0.25  # a lid this fraction of its rest opening away from it costs as much
# How much of the whole face's cost a region's rest frames weigh (1: the face's frames).
# The eyes' scores miss wide eyes on some faces (the synthetic avatar's calmest-scoring eyes
# were 0.025 IOD wider than its neutral's; the face's, within 0.006), so the eyes rest with
# the face; the mouth leans on it a little; the brows not at all: the head coordinates move
# with the jaw (the brows 2 mm lower while talking on one clip), and brows rested on the
# closed-mouth frames drew frown lines through all the talking.
OTHERS_WEIGHT = {"brows": 0.0, "eyes": 1.0, "mouth": 0.25}
REFERENCE_SHARE = 0.2  # the share of calmest-scoring frames whose median sets a measure's rest value
# Each region's rest is the median of its REST_SHARE most relaxed tracked frames, at least
# REST_MIN_FRAMES (fewer on shorter clips) and at most REST_MAX_FRAMES.
REST_SHARE, REST_MIN_FRAMES, REST_MAX_FRAMES = 0.05, 3, 30


@dataclass
class ActorRest:
    """The actor's rest. L = 478 landmarks, S = 52 scores.

    Attributes:
        face: (L, 3) float32 head-coordinate landmarks (cm) of the whole face at rest (the
            calmest frames over all regions): what the network maps onto the character's rest.
        landmarks: (L, 3) float32 the same, each region's from its own rest frames.
        scores: (S,) float32 the scores at rest, each from its region's rest frames
            (scores of no region, ``_neutral``: from the face's).
        frames: region (:data:`REGIONS`, and ``"face"``) -> (K,) int frames it took; empty
            when the rest came from outside the clip.
        source: "clip", "frame N", "image PATH" or "clip PATH".
    """

    face: np.ndarray
    landmarks: np.ndarray
    scores: np.ndarray
    frames: dict[str, np.ndarray]
    source: str = "clip"

    @property
    def single_frame(self) -> int | None:
        """The one frame the face and every region took (a forced neutral frame), else None."""
        sets = {tuple(int(i) for i in self.frames.get(r, ())) for r in (*REGIONS, FACE)}
        only = next(iter(sets)) if len(sets) == 1 else ()
        return only[0] if len(only) == 1 else None


@functools.lru_cache(maxsize=1)
def landmark_regions() -> np.ndarray:
    """(478,) int index into :data:`REGIONS` of each tracker landmark: the eyes' within
    :data:`EYE_REACH_CM` of their contours (and the irises), every other landmark above the
    eyes the region of its nearest brow or mouth feature, and below them the mouth's."""
    vertices = load_canonical_mesh().vertices.astype(np.float64)
    near = {r: np.linalg.norm(vertices[:, None] - vertices[None, list(_FEATURES[r])], axis=-1).min(1) for r in REGIONS}
    above_eyes = vertices[:, 1] > vertices[list(_FEATURES["eyes"]), 1].mean()  # below them: cheeks, the mouth's
    out = np.where((near["brows"] < near["mouth"]) & above_eyes, REGIONS.index("brows"), REGIONS.index("mouth"))
    out[near["eyes"] < EYE_REACH_CM] = REGIONS.index("eyes")
    return np.concatenate([out, np.full(10, REGIONS.index("eyes"))]).astype(np.int64)


def region_score_columns(names: list[str], gaze: bool = True) -> dict[str, list[int]]:
    """Region -> the columns of ``names`` (scores) that belong to it; ``gaze`` False leaves
    out ``eyeLook*`` (looking around is no expression: the eyes' rest is where they look
    straight ahead with open lids, which the geometry tells better than those scores)."""
    return {r: [k for k, n in enumerate(names) if n.startswith(_SCORE_PREFIXES[r])
                and (gaze or not n.startswith("eyeLook"))] for r in REGIONS}


def pair_distances(landmarks_head, measures: dict[str, tuple], chunk: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """(F, K) float64 each measure's mean distance (cm) over its landmark pairs (K measures,
    in the dict's order) and the inter-ocular distance (F,) cm, of head-coordinate landmarks
    (F, L, 3) (an array or a disk-backed FrameArray: only these points are read, ``chunk``
    frames at a time)."""
    ids = sorted({i for pairs in measures.values() for p in pairs for i in p} | set(IOD_PAIR))
    col = {i: k for k, i in enumerate(ids)}
    pts = take_points(landmarks_head, ids, chunk)
    out = np.empty((len(pts), len(measures)))
    for k, pairs in enumerate(measures.values()):
        out[:, k] = np.mean([np.linalg.norm(pts[:, col[a]] - pts[:, col[b]], axis=-1) for a, b in pairs], 0)
    return out, np.linalg.norm(pts[:, col[IOD_PAIR[0]]] - pts[:, col[IOD_PAIR[1]]], axis=-1)


def rest_geometry(landmarks_head, chunk: int = 512) -> np.ndarray:
    """(F, 4) float64 :data:`GEOMETRY` of head-coordinate landmarks (F, L, 3) (an array or a
    disk-backed FrameArray), in inter-ocular distances of each frame."""
    dist, iod = pair_distances(landmarks_head, {g: GEOMETRY_PAIRS[g] for g in GEOMETRY}, chunk)
    return dist / np.maximum(iod, 1e-9)[:, None]


def region_costs(scores: np.ndarray, names: list[str], geometry: np.ndarray, speed: np.ndarray,
                 valid: np.ndarray) -> np.ndarray:
    """(F, 3) how far each frame is from rest, per region (lower: more relaxed).

    A region's cost is the sum of its squared scores plus its geometry's distance from
    rest (brows: height against its rest value, in :data:`BROW_SCALE`; eyes: each lid's
    opening against its rest value, in :data:`LID_SCALE`; mouth: the lip gap in
    :data:`CLOSED_GAP`), raised by head speed as the neutral pick's cost is. A measure's
    rest value is its median over the :data:`REFERENCE_SHARE` of frames whose region
    scores lowest.

    Args:
        scores: (F, S) the tracker's scores, names ``names``.
        geometry: (F, 4) :func:`rest_geometry`.
        speed: (F,) head speed (:func:`~capture2face.tracking.neutral.head_speed`).
        valid: (F,) bool tracked frames (the only candidates).
    """
    scores = np.nan_to_num(np.asarray(scores, np.float64))
    g = np.asarray(geometry, np.float64)
    pool = np.asarray(valid, bool) if np.any(valid) else np.ones(len(g), bool)
    cols = region_score_columns(names, gaze=False)
    energy = {r: (scores[:, c] ** 2).sum(1) if c else np.zeros(len(g)) for r, c in cols.items()}
    brow = g[:, GEOMETRY.index("brow_height")]
    lids = g[:, [GEOMETRY.index("lid_right"), GEOMETRY.index("lid_left")]]
    # Each measure's rest value: its median over the frames whose region scores lowest
    # (the scores say which frames are calm; the geometry then ranks them, both ways).
    calm = {r: _lowest(energy[r], pool, REFERENCE_SHARE) for r in ("brows", "eyes")}
    brow_ref = np.median(brow[calm["brows"]])
    lid_ref = np.maximum(np.median(lids[calm["eyes"]], 0), 1e-6)
    geo = {"brows": ((brow - brow_ref) / BROW_SCALE) ** 2,
           "eyes": (((lids - lid_ref) / (LID_SCALE * lid_ref)) ** 2).sum(1),
           "mouth": (g[:, GEOMETRY.index("lip_gap")] / CLOSED_GAP) ** 2}
    steady = 1.0 + (np.asarray(speed, np.float64) / STEADY_SPEED) ** 2
    cost = np.stack([energy[r] + geo[r] for r in REGIONS], 1) * steady[:, None]
    cost[~pool] = np.inf
    return cost


def _lowest(values: np.ndarray, pool: np.ndarray, share: float) -> np.ndarray:
    """(K,) the ``share`` of the ``pool`` (F,) bool frames with the lowest ``values`` (F,)."""
    frames = np.flatnonzero(pool)
    k = max(1, int(round(share * len(frames))))
    return frames[np.argsort(values[frames], kind="stable")[:k]]


def rest_frame_count(n_valid: int) -> int:
    """How many frames a region's rest takes on a clip of ``n_valid`` tracked frames."""
    return int(min(n_valid, max(REST_MIN_FRAMES, min(REST_MAX_FRAMES, round(REST_SHARE * n_valid)))))


def clip_rest(landmarks_head, scores: np.ndarray, names: list[str], pose: np.ndarray, times: np.ndarray,
              valid: np.ndarray, geometry: np.ndarray | None = None) -> ActorRest:
    """Each region's rest from its most relaxed frames (:func:`region_costs`), the face's
    from the frames whose regions' costs sum lowest.

    Args:
        landmarks_head: (F, L, 3) head-coordinate landmarks (array or FrameArray).
        scores: (F, S) scores named ``names``; pose: (F, 4, 4) head pose; times: (F,) s.
        valid: (F,) bool tracked frames.
        geometry: (F, 4) :func:`rest_geometry` when already measured.
    """
    geometry = rest_geometry(landmarks_head) if geometry is None else np.asarray(geometry, np.float64)
    cost = region_costs(scores, names, geometry, head_speed(pose, times), valid)
    n_valid = int(np.isfinite(cost[:, 0]).sum()) or len(cost)
    k = rest_frame_count(n_valid)
    total = cost.sum(1)
    share = np.array([OTHERS_WEIGHT[r] for r in REGIONS])
    tracked = np.isfinite(total)
    own = np.full_like(cost, np.inf)  # untracked frames stay out (0 x inf would let them in)
    own[tracked] = (1.0 - share) * cost[tracked] + share * total[tracked, None]
    frames = {r: np.sort(np.argsort(c, kind="stable")[:k]) for r, c in zip((*REGIONS, FACE), (*own.T, total))}
    return _rest_of_frames(landmarks_head, scores, names, frames, "clip")


def frame_rest(landmarks_head, scores: np.ndarray, names: list[str], frame: int,
               source: str | None = None) -> ActorRest:
    """The rest of one frame for every region (``--neutral-frame``)."""
    frames = {r: np.array([int(frame)]) for r in (*REGIONS, FACE)}
    return _rest_of_frames(landmarks_head, scores, names, frames, source or f"frame {int(frame)}")


def _median_rows(landmarks_head, frames) -> np.ndarray:
    """(L, 3) float32 median of the given frames' landmarks (read one frame at a time)."""
    return np.median(np.stack([np.asarray(landmarks_head[int(f)], np.float32) for f in frames]), 0)


def _rest_of_frames(landmarks_head, scores: np.ndarray, names: list[str], frames: dict[str, np.ndarray],
                    source: str) -> ActorRest:
    regions = landmark_regions()[:landmarks_head.shape[1]]
    face = _median_rows(landmarks_head, frames[FACE])
    landmarks = face.copy()
    scores = np.asarray(scores, np.float32)
    rest_scores = np.median(scores[frames[FACE]], 0)
    cols = region_score_columns(names)
    for i, r in enumerate(REGIONS):
        if np.array_equal(frames[r], frames[FACE]):
            continue
        landmarks[regions == i] = _median_rows(landmarks_head, frames[r])[regions == i]
        rest_scores[cols[r]] = np.median(scores[frames[r]][:, cols[r]], 0)
    return ActorRest(face=face, landmarks=landmarks, scores=rest_scores.astype(np.float32), frames=frames,
                     source=source)


def rest_figures(rest: ActorRest, names: list[str]) -> dict[str, dict[str, float]]:
    """Region -> its geometry at rest (IOD) and the largest of its scores at rest."""
    g = rest_geometry(rest.landmarks[None])[0]
    cols = region_score_columns(names)
    own = {"brows": ("brow_height",), "eyes": ("lid_right", "lid_left"), "mouth": ("lip_gap",)}
    return {r: {**{m: round(float(g[GEOMETRY.index(m)]), 4) for m in own[r]},
                "largest_score": round(float(rest.scores[cols[r]].max()) if cols[r] else 0.0, 3)}
            for r in REGIONS}


def aligned_rest(rest: ActorRest, landmarks_head, valid: np.ndarray) -> ActorRest:
    """A rest from outside the clip (a photo, another take) moved onto the clip's head
    coordinates: the similarity (scale, rotation, shift) that best lays its face oval and
    nose, which expressions barely move, onto the clip's median face."""
    frames = np.flatnonzero(np.asarray(valid, bool))
    pick = frames[np.linspace(0, len(frames) - 1, min(len(frames), 60)).astype(int)] if len(frames) else np.arange(1)
    target = np.median(np.stack([np.asarray(landmarks_head[int(f)], np.float64)[_STABLE] for f in pick]), 0)
    scale, rot, shift = similarity(rest.face[_STABLE].astype(np.float64), target)
    move = lambda pts: (scale * pts.astype(np.float64) @ rot.T + shift).astype(np.float32)  # noqa: E731
    return dataclasses.replace(rest, face=move(rest.face), landmarks=move(rest.landmarks),
                               frames={r: np.zeros(0, np.int64) for r in (*REGIONS, FACE)})


# The face oval's upper half and the nose bridge: the points no expression moves much.
_STABLE = np.array([10, 21, 54, 67, 103, 109, 127, 162, 234, 251, 284, 297, 332, 338, 356, 389, 454,
                    6, 168, 197, 195, 5, 4, 1])


def rest_fields(rest: ActorRest) -> dict:
    """The ``Track`` fields that store ``rest`` (``dataclasses.replace(track, **rest_fields(rest))``)."""
    keys = (*REGIONS, FACE)
    k = max([len(rest.frames.get(r, ())) for r in keys] + [1])
    frames = np.full((len(keys), k), -1, np.int32)
    for i, r in enumerate(keys):
        f = np.asarray(rest.frames.get(r, ()), np.int32)
        frames[i, :len(f)] = f
    return {"rest_face": rest.face.astype(np.float32), "rest_landmarks": rest.landmarks.astype(np.float32),
            "rest_scores": rest.scores.astype(np.float32), "rest_frames": frames, "rest_source": rest.source}


def actor_rest(track) -> ActorRest:
    """The rest a :class:`~capture2face.tracking.track.Track` carries; for a track without
    one (saved before rests were, or built by hand) its neutral frame's."""
    if track.rest_face is None or track.rest_landmarks is None or track.rest_scores is None:
        return frame_rest(track.landmarks_head, track.blendshapes, list(track.blendshape_names), track.neutral_frame)
    keys = (*REGIONS, FACE)
    frames = np.zeros((len(keys), 0), np.int32) if track.rest_frames is None else np.asarray(track.rest_frames)
    return ActorRest(face=np.asarray(track.rest_face, np.float32),
                     landmarks=np.asarray(track.rest_landmarks, np.float32),
                     scores=np.asarray(track.rest_scores, np.float32),
                     frames={r: frames[i][frames[i] >= 0] for i, r in enumerate(keys)},
                     source=track.rest_source or "clip")


def with_clip_rest(track):
    """``track`` with its clip's own rest (:func:`clip_rest`), as the tracker stores it."""
    rest = clip_rest(track.landmarks_head, track.blendshapes, list(track.blendshape_names), track.head_pose,
                     track.times, track.presence)
    return dataclasses.replace(track, **rest_fields(rest))


def with_frame_rest(track, frame: int):
    """``track`` resting on one frame (every region), as ``--neutral-frame`` makes it."""
    rest = frame_rest(track.landmarks_head, track.blendshapes, list(track.blendshape_names), frame)
    return dataclasses.replace(track, neutral_frame=int(frame), **rest_fields(rest))


# A region "never relaxes" when, at its calmest frames, a score of its own (gaze left out)
# still reads above this, or (mouth) the lips stay this far apart (IOD). On the shared clips
# and the synthetic faces the calmest frames reach at most 0.38 (brows: raised all through a clip),
# 0.64 (eyes: squints MediaPipe scores on some faces all through a clip) and 0.05 IOD of lip
# gap (docs/rest.md).
NEVER_RELAXED = {"brows": 0.5, "eyes": 0.8, "mouth": 0.08}


def rest_warnings(rest: ActorRest, names: list[str]) -> list[str]:
    """One line per region that never relaxes in the clip, saying what to do about it."""
    if not len(rest.frames.get(FACE, ())):
        return []  # a rest from outside the clip: the user chose it
    cols = region_score_columns(names, gaze=False)
    figures = rest_figures(rest, names)
    out = []
    for region in REGIONS:
        if region == "mouth":
            gap = figures[region]["lip_gap"]
            if gap > NEVER_RELAXED[region]:
                out.append(f"the lips never close in this clip ({gap:.2f} inter-ocular distances apart at their "
                           "calmest): mouth shapes are measured from parted lips")
            continue
        if not cols[region]:
            continue
        k = cols[region][int(np.argmax(rest.scores[cols[region]]))]
        if rest.scores[k] > NEVER_RELAXED[region]:
            out.append(f"the {region} never relax in this clip ({names[k]} {rest.scores[k]:.2f} at their calmest): "
                       f"their curves and wrinkles are measured from that expression")
    if out:
        out[-1] += "; give a frame at rest (--neutral-frame N) or a take at rest (--neutral-image, --neutral-clip)"
    return out


def rest_report(rest: ActorRest, names: list[str]) -> dict:
    """report.json's ``rest``: where it came from and, per region (and the face), the frames
    it took and its figures (:func:`rest_figures`; ``names``: the scores')."""
    figures = rest_figures(rest, names)
    out: dict = {"source": rest.source}
    for region in (*REGIONS, FACE):
        out[region] = {"frames": [int(f) for f in rest.frames.get(region, ())], **figures.get(region, {})}
    return out

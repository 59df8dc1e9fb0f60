"""What a calibration reads of each frame: the landmarks that expressions move, relative to
the actor's rest in inter-ocular distances (IOD), and the tracker's scores relative to
theirs. One flat vector per frame, the same for the ROM take and every clip of the actor."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from capture2face.topology import (
    BROWS,
    CHIN,
    EYE_LEFT,
    EYE_RIGHT,
    FACE_OVAL,
    IOD_PAIR,
    IRIS_LEFT,
    IRIS_RIGHT,
    LIPS_INNER,
    LIPS_OUTER,
    NOSE_WINGS,
)

# Cheek points (puffs, sneers, wide smiles move them) beside the features' contours.
CHEEKS = (50, 280, 205, 425, 187, 411, 123, 352, 36, 266)
LANDMARKS = np.array(sorted(set(BROWS + EYE_RIGHT + EYE_LEFT + IRIS_RIGHT + IRIS_LEFT + LIPS_INNER + LIPS_OUTER
                                + NOSE_WINGS + CHIN + FACE_OVAL + CHEEKS)))
# Depth is MediaPipe's least certain axis: it counts at this weight against x and y.
DEPTH_WEIGHT = 0.5
# A score's change of 1 counts as much as a landmark moving this far (IOD): the scores carry
# the fast detail the landmark filter smooths away and the lids' closure MediaPipe reads well.
SCORE_WEIGHT = 1.0
REFERENCE_DISTANCE_CM = 50.0


def rest_iod(rest_landmarks: np.ndarray) -> float:
    a, b = IOD_PAIR
    return max(float(np.linalg.norm(rest_landmarks[a] - rest_landmarks[b])), 1e-6)


def frame_features(landmarks_head, scores, rest_landmarks: np.ndarray, rest_scores: np.ndarray,
                   score_columns: np.ndarray, frames=slice(None)) -> np.ndarray:
    """(F, D) float64 feature vectors of ``frames``.

    Args:
        landmarks_head: (F_all, 478, 3) head coordinates (cm); an array or a memmap.
        scores: (F_all, S) the tracker's scores.
        rest_landmarks: (478, 3) the actor's rest in the same coordinates.
        rest_scores: (S,) the scores at rest.
        score_columns: (C,) the score columns read (the ARKit-named ones).
    """
    iod = rest_iod(rest_landmarks)
    lm = (np.asarray(landmarks_head[frames], np.float64)[:, LANDMARKS] - rest_landmarks[LANDMARKS]) / iod
    lm[..., 2] *= DEPTH_WEIGHT
    sc = np.nan_to_num(np.asarray(scores[frames], np.float64)[:, score_columns] - rest_scores[score_columns])
    return np.concatenate([lm.reshape(len(lm), -1), SCORE_WEIGHT * sc], 1)


# Landmark groups whose motion is judged apart (an expression moves one or two of them):
# indices into the landmark part of a feature vector (each landmark's x, y, z).
_POS = {int(lm): i for i, lm in enumerate(LANDMARKS)}
GROUPS: dict[str, np.ndarray] = {
    name: np.array([3 * _POS[i] + a for i in idx for a in range(3)])
    for name, idx in {"brows": BROWS, "eyes": EYE_RIGHT + EYE_LEFT, "irises": IRIS_RIGHT + IRIS_LEFT,
                      "lips": LIPS_INNER + LIPS_OUTER, "jaw": CHIN + FACE_OVAL, "cheeks": CHEEKS + NOSE_WINGS}.items()
}


def pose_terms(head_pose: np.ndarray) -> np.ndarray:
    """(F, 13) float64 what the tracker's head-coordinate reading depends on besides the
    face, from (F, 4, 4) head -> camera poses: the head's rotation from facing the camera
    (rotation vector, its squares and products), its nearness (:data:`REFERENCE_DISTANCE_CM`
    over its distance, less 1), its offset from the optical axis, and 1. MediaPipe's
    landmarks of a still face shift with the head's pose by as much as a frown moves the
    brows; a calibration learns this actor's shift from the take."""
    pose = np.asarray(head_pose, np.float64)
    rv = Rotation.from_matrix(pose[:, :3, :3]).as_rotvec()
    t = pose[:, :3, 3]
    depth = np.maximum(np.abs(t[:, 2:3]), 1e-6)
    cross = rv[:, [0, 1, 0]] * rv[:, [1, 2, 2]]
    return np.concatenate([rv, rv * rv, cross, REFERENCE_DISTANCE_CM / depth - 1.0, t[:, :2] / depth,
                           np.ones((len(pose), 1))], 1)


def group_motion(features: np.ndarray) -> np.ndarray:
    """(F, G) the RMS change of each of :data:`GROUPS` (IOD)."""
    return np.stack([np.sqrt((features[:, g] ** 2).mean(1)) for g in GROUPS.values()], 1)


# Which landmark groups and scores an ARKit curve moves, by its name's start: a step's
# basis keeps only its curves' regions (elsewhere the take's hold holds the tracker's
# noise, which would let the step explain motion it does not make).
_REGION_GROUPS = {"brow": ("brows",), "eye": ("eyes", "irises"), "jaw": ("lips", "jaw"),
                  "mouth": ("lips", "jaw", "cheeks"), "cheek": ("cheeks", "lips"), "nose": ("cheeks", "lips"),
                  "tongue": ("lips",)}
_REGION_SCORES = {"brow": ("brow",), "eye": ("eye",), "jaw": ("jaw", "mouth"), "mouth": ("mouth", "jaw"),
                  "cheek": ("cheek", "mouth"), "nose": ("nose", "mouth"), "tongue": ("tongue",)}


def curve_region(name: str) -> str:
    """The region an ARKit curve moves (\"brow\", \"eye\", \"jaw\", \"mouth\", ...), by its name's start."""
    return next((r for r in _REGION_GROUPS if name.startswith(r)), "mouth")


def curve_groups(curves) -> np.ndarray:
    """The indices into :data:`GROUPS` (and :func:`group_motion`'s columns) of the landmark
    groups the regions of ``curves`` (ARKit names) move."""
    wanted = {g for name in curves for g in _REGION_GROUPS[curve_region(name)]}
    return np.array([i for i, g in enumerate(GROUPS) if g in wanted], int)


def curve_mask(curves, score_names: list[str], score_columns: np.ndarray) -> np.ndarray:
    """(D,) bool the features of the regions ``curves`` (ARKit names) move."""
    n_lm = 3 * len(LANDMARKS)
    mask = np.zeros(n_lm + len(score_columns), bool)
    for name in curves:
        region = curve_region(name)
        for g in _REGION_GROUPS[region]:
            mask[GROUPS[g]] = True
        starts = _REGION_SCORES[region]
        mask[n_lm:] |= np.array([score_names[c].startswith(starts) for c in score_columns])
    return mask

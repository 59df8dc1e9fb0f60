"""The lids of a head driven by its presets' recipes, filled to follow the actor's closing.

A VRM head's only lid morphs are its blinks, and the recipes give them the clip's blink
curves (:mod:`capture2face.rig.morph_conventions`). The actor's lids also close with a
squint and when looking down, which the recipes give to no preset (Godette on d12: the
actor's eye opening falls 0.67 per unit of ``eyeSquint`` beside 0.75 per unit of
``eyeBlink``; Godette's by 0.00-0.05). Here each eye's closing (the weights times each
morph's closing of that eye's lid pair at 1, a share of the eye's rest opening) is raised,
by adding that eye's own blink, to the actor's closing of the same lids (the tracked lid
pair's gap under its rest, a share of the rest): the eye follows the actor's opening
relative to its own, as the eye measures read it, up to its blink at 1. A frame already
that closed keeps its weights; the eyes never open wider than at rest (no preset does).
"""

from __future__ import annotations

import numpy as np

from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.rig.morph_conventions import blink_morphs
from capture2face.topology import LIDS_LEFT, LIDS_RIGHT


def actor_closing(landmarks_head: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(F, 2) how far the actor's lids (right, left) are closed: 1 - the lid pair's gap
    over its gap at ``rest`` (L, 3), >= 0. ``landmarks_head``: (F, L, 3)."""
    lm, rest = np.asarray(landmarks_head), np.asarray(rest, np.float64)
    out = []
    for a, b in (LIDS_RIGHT, LIDS_LEFT):
        gap = np.linalg.norm(lm[:, a] - lm[:, b], axis=-1).astype(np.float64)
        out.append(1.0 - gap / max(float(np.linalg.norm(rest[a] - rest[b])), 1e-9))
    return np.maximum(np.stack(out, 1), 0.0)


def morph_closings(rig: FaceRig) -> np.ndarray:
    """(M, 2) how far each morph at 1 closes the head's lid pairs (right, left), a share of
    their rest gap (negative: opens)."""
    ids = [*LIDS_RIGHT, *LIDS_LEFT]
    rest = landmark_points(rig, rig.vertices, ids)
    posed = landmark_points(rig, rig.vertices[None] + rig.morph_positions, ids)
    gap0 = np.linalg.norm(rest[[0, 2]] - rest[[1, 3]], axis=-1)
    gaps = np.linalg.norm(posed[:, [0, 2]] - posed[:, [1, 3]], axis=-1)
    return 1.0 - gaps / np.maximum(gap0, 1e-9)


def fill_lids(weights: np.ndarray, rig: FaceRig, closing: np.ndarray) -> np.ndarray:
    """(F, M) ``weights`` with each eye's own blink raised where that eye closes less than
    ``closing`` (F, 2) (:func:`actor_closing`); unchanged for a head without both one-eye
    blinks or whose blinks do not close its lids."""
    found = blink_morphs(rig.morph_names)
    if found is None:
        return weights
    sides = [found[2], found[1]]  # (right, left): the character's right eye is the tracker's LIDS_RIGHT
    closings = morph_closings(rig)
    reach = closings[sides, [0, 1]]
    if (reach <= 0.1).any():
        return weights
    short = np.maximum(np.asarray(closing, np.float64) - np.asarray(weights, np.float64) @ closings, 0.0)
    out = np.array(weights, np.float32, copy=True)
    out[:, sides] = np.clip(out[:, sides] + short / reach, 0.0, 1.0)
    return out

"""The mouth's opening of a head driven by its presets' recipes, filled to follow the actor's.

The recipes (:mod:`capture2face.rig.morph_conventions`) split the jaw's opening between a
head's vowel shapes by the lips' shape, and each shape opens its own way: Godette's ``E``
opens its lips 0.3 cm, ``U`` 1.0, ``A`` 2.1, ``O`` 2.6 (the rig's landmarks, ``LIP_GAP``).
So in speech, where small openings go to the spread and round shapes, the mouth opened far
less than the jaw. Here each frame's opening (the weights times each morph's own opening at
1, summed) is raised, by adding the open vowels (``A`` / ``aa``, and ``O`` / ``oh`` as far as
the actor's lips are rounded: ``mouthFunnel`` or ``mouthPucker``), to the actor's opening as a
share of a human's full one (the tracked lips' gap over the built-in avatar's ``jawOpen``
range, :data:`HUMAN_OPEN_IOD`) times the head's own full range (the most any one morph
opens it): the opening follows the actor's at the head's range, the lips' shape still the
recipes'. A frame already open that far keeps its weights. (The clip's ``jawOpen`` alone
understates the actor's opening: on d12 it reads 0.56 of the lips' gap at a human's range,
the rest being the lips' own morphs, which a vowel set has no room for.)
"""

from __future__ import annotations

import numpy as np

from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.topology import IOD_PAIR, LIP_GAP

OPEN_VOWELS = ("a", "aa", "viseme_aa")  # the open shape, where a head has one
ROUND_VOWELS = ("o", "oh", "viseme_o")  # the round open shape
HUMAN_OPEN_IOD = 0.213  # the built-in avatar's jawOpen at 1 parts its lips 0.213 inter-ocular distances


def actor_opening(landmarks_head: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(F,) the actor's lips' gap (``LIP_GAP``) beyond its rest, as a share of a human's
    full opening (:data:`HUMAN_OPEN_IOD`), >= 0.

    Args:
        landmarks_head: (F, L, 3) tracked landmarks; rest: (L, 3) the actor's rest."""
    lm, rest = np.asarray(landmarks_head), np.asarray(rest, np.float64)
    gap = np.linalg.norm(lm[:, LIP_GAP[0]] - lm[:, LIP_GAP[1]], axis=-1).astype(np.float64)
    iod = max(float(np.linalg.norm(rest[IOD_PAIR[0]] - rest[IOD_PAIR[1]])), 1e-6)
    rest_gap = float(np.linalg.norm(rest[LIP_GAP[0]] - rest[LIP_GAP[1]]))
    return np.maximum(gap - rest_gap, 0.0) / iod / HUMAN_OPEN_IOD


def morph_openings(rig: FaceRig) -> np.ndarray:
    """(M,) how far each morph at 1 parts the lips (``LIP_GAP``, cm; negative: closes)."""
    rest = landmark_points(rig, rig.vertices, list(LIP_GAP))
    posed = landmark_points(rig, rig.vertices[None] + rig.morph_positions, list(LIP_GAP))
    return np.linalg.norm(posed[:, 0] - posed[:, 1], axis=-1) - np.linalg.norm(rest[0] - rest[1])


def lips_round(arkit_names: list[str], curves: np.ndarray) -> np.ndarray:
    """(F,) how round the actor's lips are: the larger of ``mouthFunnel``, ``mouthPucker``."""
    cols = [list(arkit_names).index(n) for n in ("mouthFunnel", "mouthPucker") if n in arkit_names]
    return np.asarray(curves, np.float64)[:, cols].max(1) if cols else np.zeros(len(curves))


def fill_opening(weights: np.ndarray, rig: FaceRig, share: np.ndarray, rounded: np.ndarray | None = None) -> np.ndarray:
    """(F, M) ``weights`` with the open vowels raised where the mouth opens less than
    ``share`` (F,) (:func:`actor_opening`) of the head's full range (the module docs), the
    round one by ``rounded`` (F,) of the shortfall (:func:`lips_round`; None: 0);
    unchanged for a head without an open vowel or a morph that opens its mouth."""
    names = [str(n).lower().rsplit(".", 1)[-1] for n in rig.morph_names]
    vowel = next((names.index(v) for v in OPEN_VOWELS if v in names), None)
    if vowel is None:
        return weights
    openings = morph_openings(rig)
    full = float(openings.max())
    if full <= 0 or openings[vowel] <= 0.1 * full:
        return weights
    short = np.maximum(np.asarray(share, np.float64), 0.0) * full - np.asarray(weights, np.float64) @ openings
    short = np.maximum(short, 0.0)
    round_vowel = next((names.index(v) for v in ROUND_VOWELS if v in names), None)
    out = np.array(weights, np.float32, copy=True)
    if round_vowel is not None and rounded is not None and openings[round_vowel] > 0.1 * full:
        part = np.clip(np.asarray(rounded, np.float64), 0.0, 1.0) * short
        out[:, round_vowel] = np.clip(out[:, round_vowel] + part / openings[round_vowel], 0.0, 1.0)
        short = short - part
    out[:, vowel] = np.clip(out[:, vowel] + short / openings[vowel], 0.0, 1.0)
    return out

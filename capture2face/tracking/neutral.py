"""The neutral frame: the calmest face with a steady head.

Expression energy is the sum of squared blendshape scores, leaving out ``_neutral`` (a bias
term, not an expression) and the ``eyeLook*`` gaze scores (looking around is not an
expression and does not deform the face). A moving head raises a frame's cost:
``energy * (1 + (speed / 10 cm/s)^2)``, so a still head (no motion blur, no lag) wins among
equally calm faces, but a merely slow head never makes an expressive frame the neutral
one (a hard speed gate did that on real clips). Only tracked frames are candidates.

The scores alone let a face with its lips apart win (MediaPipe scores jawOpen 0.2-0.3 on
a relaxed open mouth: on real clips the pick had the lips 0.17-0.22 inter-ocular
distances apart), and the retargeting takes the neutral's lip gap as the character's
closed mouth, so every later opening came out at a half. The lips' own gap (landmarks
13-14, in inter-ocular distances, measured on the head-coordinate landmarks) is added to
the energy: ``energy + (gap / CLOSED_GAP)^2``.
"""

from __future__ import annotations

import numpy as np

from capture2face.tracking.head_pose import split_pose

STEADY_SPEED = 10.0  # cm/s of surface motion (head speed) that doubles a frame's cost
CLOSED_GAP = 0.05  # lip gap (inter-ocular distances) that costs as much as a full expression


def expression_energy(blendshapes: np.ndarray, names: list[str]) -> np.ndarray:
    """(F,) sum of squared expression scores of ``blendshapes`` (F, S)."""
    keep = np.array([not (n == "_neutral" or n.startswith("eyeLook")) for n in names], bool)
    return (np.asarray(blendshapes, np.float64)[:, keep] ** 2).sum(1)


def head_speed(pose: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(F,) head speed: translation in cm/s plus rotation in rad/s times 10 cm."""
    pose = np.asarray(pose, np.float64)
    if pose.shape[0] < 2:
        return np.zeros(pose.shape[0])
    _, rot, _ = split_pose(pose)
    dt = np.maximum(np.diff(times), 1e-6)
    ang = (rot[1:] * rot[:-1].inv()).magnitude() / dt
    lin = np.linalg.norm(np.diff(pose[:, :3, 3], axis=0), axis=1) / dt
    step = lin + 10.0 * ang  # (F-1,) between frames; a frame takes its neighbours' mean
    return np.concatenate([[step[0]], 0.5 * (step[1:] + step[:-1]), [step[-1]]])


def pick_neutral(blendshapes: np.ndarray, names: list[str], pose: np.ndarray,
                 times: np.ndarray, valid: np.ndarray, mouth_gap: np.ndarray | None = None) -> int:
    """Index of the neutral frame among ``valid`` (F,) bool frames (tracked, not filled).

    Args:
        mouth_gap: (F,) lip gap in inter-ocular distances (13-14 over 33-263); None
            judges by the scores alone.
    """
    valid = np.asarray(valid, bool)
    if not valid.any():
        valid = np.ones_like(valid)
    energy = expression_energy(blendshapes, names)
    if mouth_gap is not None:
        energy = energy + (np.asarray(mouth_gap, np.float64) / CLOSED_GAP) ** 2
    cost = energy * (1.0 + (head_speed(pose, times) / STEADY_SPEED) ** 2)
    pool = np.flatnonzero(valid)
    return int(pool[np.argmin(cost[pool])])

"""The neutral frame: the calmest face with a steady head.

Expression energy is the sum of squared blendshape scores, leaving out ``_neutral`` (a bias
term, not an expression) and the ``eyeLook*`` gaze scores (looking around is not an
expression and does not deform the face). Among tracked frames whose head speed is at
most the median head speed, the frame with the lowest energy wins; a still head keeps
motion blur and pose-dependent landmark bias out of the reference.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def expression_energy(blendshapes: np.ndarray, names: list[str]) -> np.ndarray:
    """(F,) sum of squared expression scores of ``blendshapes`` (F, S)."""
    keep = np.array([not (n == "_neutral" or n.startswith("eyeLook")) for n in names], bool)
    return (np.asarray(blendshapes, np.float64)[:, keep] ** 2).sum(1)


def head_speed(pose: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(F,) head speed: translation in cm/s plus rotation in rad/s times 10 cm."""
    pose = np.asarray(pose, np.float64)
    if pose.shape[0] < 2:
        return np.zeros(pose.shape[0])
    m3 = pose[:, :3, :3]
    rot = Rotation.from_matrix(m3 / np.cbrt(np.linalg.det(m3))[:, None, None])
    dt = np.maximum(np.diff(times), 1e-6)
    ang = (rot[1:] * rot[:-1].inv()).magnitude() / dt
    lin = np.linalg.norm(np.diff(pose[:, :3, 3], axis=0), axis=1) / dt
    step = lin + 10.0 * ang  # (F-1,) between frames; a frame takes its neighbours' mean
    return np.concatenate([[step[0]], 0.5 * (step[1:] + step[:-1]), [step[-1]]])


def pick_neutral(blendshapes: np.ndarray, names: list[str], pose: np.ndarray,
                 times: np.ndarray, valid: np.ndarray) -> int:
    """Index of the neutral frame among ``valid`` (F,) bool frames (tracked, not filled)."""
    valid = np.asarray(valid, bool)
    if not valid.any():
        valid = np.ones_like(valid)
    energy = expression_energy(blendshapes, names)
    speed = head_speed(pose, times)
    steady = valid & (speed <= np.median(speed[valid]) + 1e-9)
    pool = steady if steady.any() else valid
    return int(np.flatnonzero(pool)[np.argmin(energy[pool])])

"""Dutreve's retargeting onto an ARKit character (ARKit-named morphs, no face bones).

The feature-point network maps the actor's landmarks onto the character's landmark points
(as for any rig); the character's morph weights are then solved, bounded to [0, 1], so
that its landmark points follow the mapped ones (:mod:`capture2face.retarget.solve`,
morphs only: the model is :func:`~capture2face.rig.feature_points.landmark_basis`).

The clip's ARKit curves (:func:`~capture2face.retarget.arkit.arkit_curves`) are the prior:

* morphs the feature points cannot see take their curve as it is (:data:`CURVE_ONLY`: the
  cheeks' puff, the lips' roll, the tongue, the eyes' look morphs, whose lid motion is
  the gaze's and not an expression; and any morph that moves no landmark by more than
  ``min_motion`` inter-ocular distances); their motion is taken off the mapped points
  before the solve, so the solved morphs explain only the rest;
* the solved morphs are pulled towards their curves, ``strength |w - curve|^2`` (in
  the fit's units, cm^2): where several morphs could explain the same landmark motion
  (a smile or a cheek squint), the one the tracker's scores name wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.retarget.solve import LinearRigModel
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.feature_points import landmark_basis

#: ARKit morphs driven by their curves alone: the tracker's landmarks do not show them
#: (a puffed cheek, a rolled lip, the tongue) or show them as something else (the eyes'
#: look morphs move the lids with the gaze).
CURVE_ONLY = frozenset({
    "cheekPuff", "tongueOut", "mouthRollLower", "mouthRollUpper",
    "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight",
    "eyeLookOutLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight",
})


@dataclass
class MorphSolve:
    """The linear model of an ARKit character's landmark points.

    Attributes:
        model: rest (N, 3) and d(points)/d(w) of the solved morphs (``model.morphs``).
        fixed: (Mf,) morphs that take their curve (:data:`CURVE_ONLY`, or moving no
            landmark); morphs in neither list are 0 on the solve's side.
        fixed_deltas: (Mf, N, 3) their landmark deltas.
    """

    model: LinearRigModel
    fixed: np.ndarray
    fixed_deltas: np.ndarray


def morph_solve(rig, landmarks: np.ndarray, min_motion: float) -> MorphSolve:
    """Split the rig's morphs into solved and curve-only ones at ``landmarks`` (N,).

    Args:
        min_motion: inter-ocular distances; a morph whose largest landmark motion is below
            it is curve-only.
    """
    rest, deltas = landmark_basis(rig, landmarks)
    motion = np.linalg.norm(deltas, axis=2).max(1) if len(landmarks) else np.zeros(rig.n_morphs)
    named = arkit_morphs(rig.morph_names)
    fixed = np.array([named.get(m) in CURVE_ONLY or motion[m] < min_motion * rig.interocular()
                      for m in range(rig.n_morphs)], bool)
    solved = np.flatnonzero(~fixed)
    matrix = np.concatenate([rigid_columns(rest), deltas[solved].reshape(len(solved), -1).T], 1)  # (3N, 6 + Ms)
    model = LinearRigModel(rest=rest, matrix=matrix, free_bones=np.zeros(0, np.int64), morphs=solved, n_rigid=6)
    return MorphSolve(model=model, fixed=np.flatnonzero(fixed), fixed_deltas=deltas[fixed])


def rigid_columns(rest: np.ndarray) -> np.ndarray:
    """(3N, 6) d(points)/d(translation, small rotation about the centroid) of ``rest``
    (N, 3): the head motion the pose removal leaves in the landmarks, which no morph
    explains (the default avatar's bones follow it; here it is solved and dropped)."""
    p = rest - rest.mean(0)
    n = len(p)
    cols = np.zeros((n, 3, 6))
    cols[:, :, :3] = np.eye(3)
    for k in range(3):  # d(omega x p)/d(omega_k) = e_k x p
        cols[:, :, 3 + k] = np.cross(np.eye(3)[k], p)
    return cols.reshape(3 * n, 6)


class CurveShifted:
    """Mapped feature points with the curve-only morphs' motion taken off, by window.

    Args:
        mapped: :class:`~capture2face.retarget.windows.MappedPoints`.
        solve: the :class:`MorphSolve`.
        prior: (F, M) the curves as morph weights.
    """

    def __init__(self, mapped, solve: MorphSolve, prior: np.ndarray):
        self.mapped, self.solve, self.prior = mapped, solve, prior
        self.windows, self.frames = mapped.windows, mapped.frames

    def read(self, w) -> np.ndarray:
        pts = self.mapped.read(w)
        d = self.solve.fixed_deltas
        if not len(d):
            return pts
        shift = (self.prior[w.start:w.stop, self.solve.fixed].astype(np.float64) @ d.reshape(len(d), -1))
        return pts - shift.reshape(pts.shape)

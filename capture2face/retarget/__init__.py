"""Retargeting: a ``Track`` (the source face) onto a ``FaceRig`` (the character) -> ``Animation``.

1. Feature points (Dutreve 2008): an RBF network trained at the neutral frame maps the
   source's landmarks (head coordinates) onto the character's feature points
   (:mod:`capture2face.retarget.rbf`).
2. Bones and morph weights that reproduce the mapped feature points through the rig's own
   deformation (morphs, then skinning), solved jointly with bounds, a ridge and a temporal
   smoothness term (:mod:`capture2face.retarget.solve`). A character whose mesh has no
   per-landmark vertices (an imported one with only bone landmarks) takes the network's
   output at the bone landmarks as bone positions, and MediaPipe's scores as the weights
   of its ARKit-named morphs.
3. Wrinkle influences (Dutreve 2009 §5.1-5.2) and zone weights
   (:mod:`capture2face.retarget.influences`).

The driver (:func:`retarget`, :class:`RetargetOptions`) lives in
:mod:`capture2face.retarget.driver`; this package re-exports it. Patch names there, where
they are used (a patch of this package's copy changes nothing).
"""

from __future__ import annotations

from capture2face.errors import CaptureError
from capture2face.retarget import influences as inf
from capture2face.retarget.animation import Animation
from capture2face.retarget.driver import (
    FACE_OVAL, RELIABILITY_ADMM_ITERATIONS, RetargetOptions, _Blend, _fit_network, _joint_solver,
    _mediapipe_weights, _per_frame, _reliability, _residual2, _retarget, feature_correspondence,
    landmark_prior_weights, retarget, retarget_ms_per_frame, shared_blendshapes, solve_bones_weights,
)
from capture2face.retarget.rbf import FeatureMap, fit_feature_map
from capture2face.retarget.solve import LinearSolver, linear_rig_model
from capture2face.retarget.windows import MappedPoints, SpilledMedian, frame_windows

__all__ = ["Animation", "RetargetOptions", "retarget", "retarget_ms_per_frame", "feature_correspondence"]

"""Retargeting: a ``Track`` (the source face) onto a ``FaceRig`` (the character) -> ``Animation``.

1. Feature points (Dutreve 2008): an RBF network trained at the neutral frame maps the
   source's landmarks (head coordinates) onto the character's feature points
   (:mod:`capture2face.retarget.rbf`).
2. Bones and morph weights that reproduce the mapped feature points through the rig's own
   deformation (morphs, then skinning), solved jointly with bounds, a ridge and a temporal
   smoothness term (:mod:`capture2face.retarget.solve`). A character whose mesh has no
   per-landmark vertices (an imported one with only bone landmarks) takes the network's
   output at the bone landmarks as bone positions, and MediaPipe's scores as the weights
   of its ARKit-named morphs. An ARKit character (morphs, no face bones) has its morph
   weights solved from its landmark points, with the clip's ARKit curves as the prior
   (:mod:`capture2face.retarget.arkit_solve`).
3. Wrinkle influences (Dutreve 2009 §5.1-5.2) and zone weights
   (:mod:`capture2face.rig.influences`).

The driver (:func:`retarget`, :class:`RetargetOptions`) lives in
:mod:`capture2face.retarget.driver`; this package re-exports it. Patch names there, where
they are used (a patch of this package's copy changes nothing).
"""

from __future__ import annotations

from capture2face.retarget.animation import Animation
from capture2face.retarget.driver import RetargetOptions, retarget, retarget_ms_per_frame, shared_blendshapes
from capture2face.rig.feature_points import feature_correspondence

__all__ = ["Animation", "RetargetOptions", "retarget", "retarget_ms_per_frame", "feature_correspondence",
           "shared_blendshapes"]

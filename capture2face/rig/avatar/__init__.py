"""The default avatar: a FaceRig built by code from MediaPipe's canonical face mesh.

Built on first use and cached (:mod:`.cache`); nothing is downloaded. The builder
(:func:`.build.build_avatar`) runs in named steps, one module each: the skin
(:mod:`.face_mesh`, reshaped by :mod:`.variants`) and its vertex sets (:mod:`.vertex_sets`),
the parts after it (:mod:`.parts` geometry, :mod:`.layout` placement), skinning
(:mod:`.bones`, :mod:`.skinning`), morphs (:mod:`.morphs`), wrinkle poses and zones
(:mod:`.poses`) and textures (:mod:`.textures`); :mod:`.landmarks` holds the contours they
share.

Vertex layout: canonical vertices 0..467 (vertex i *is* landmark i), then the edge
midpoints of one subdivision step (skin, material 0), then the right and left eyeballs
(material 1), then the mouth interior (material 2), then the upper teeth, lower teeth and
tongue (material 3), then the head shell and the ears (material 4). The eyeballs turn about
their centres with the gaze; the upper teeth ride the head, the lower teeth and the tongue
the jaw bone and the jaw morphs.

Sides are the subject's: ``_L`` bones and ``...Left`` morphs are on the subject's left,
+x in head coordinates, u > 0.5 in texture space.
"""

from __future__ import annotations

from capture2face.io.cache import cache_dir
from capture2face.rig.avatar.bones import BONES, FOREHEAD_PIN_CM, FOREHEAD_PIN_HEAD, BoneSpec
from capture2face.rig.avatar.build import build_avatar
from capture2face.rig.avatar.cache import default_avatar, forget_built, is_cached
from capture2face.rig.avatar.face_mesh import LIP_PAIRS, close_lips
from capture2face.rig.avatar.landmarks import (
    BROW_R,
    EYE_RINGS,
    LIP_INNER_CORNERS,
    LIP_LOWER_LINES,
    LIP_UPPER_LINES,
)
from capture2face.rig.avatar.variants import VARIANTS

__all__ = ["BONES", "BROW_R", "EYE_RINGS", "FOREHEAD_PIN_CM", "FOREHEAD_PIN_HEAD", "LIP_INNER_CORNERS",
           "LIP_LOWER_LINES", "LIP_PAIRS", "LIP_UPPER_LINES", "VARIANTS", "BoneSpec", "build_avatar", "cache_dir",
           "close_lips", "default_avatar", "forget_built", "is_cached"]

"""The default avatar's face bones: where each sits, how far its skinning reaches, and its
group.

Sides are the subject's: ``_L`` bones are on the subject's left, +x in head coordinates.

Bone groups (Dutreve 2009 §5.1: a wrinkle follows a muscle, not one point, and a group's
mean influence is robust to one badly tracked bone), one per muscle system and side: each
brow (frontalis/corrugator sheet: its three bones), each eye (orbicularis oculi: both lids
and the upper cheek below the outer lid, where the crow's feet are), each cheek (zygomatic
and levator: cheek and nose wing, the nasolabial fold), the upper lip, and the lower lip
with the jaw (the chin moves with both). The mouth corners stay alone (a smile can be
one-sided). On 300 tracked synthetic frames (seeds 0-2) these groups lower the per-vertex
influence error from 0.089/0.070/0.088 (brows only) to 0.082/0.060/0.083.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture2face.topology import BROW_LEFT, BROW_RIGHT, LIDS_LEFT, LIDS_RIGHT, LIP_GAP, MOUTH_CORNERS


@dataclass(frozen=True)
class BoneSpec:
    name: str
    landmark: int
    radius: float  # cm of geodesic distance from the bone's source beyond which its weight is 0
    group: str
    # The bone's source (weight 1 before normalization): its landmark, plus the skin along
    # segments from it to these (medial, up) offsets in cm (medial = towards the midline).
    # The brows' frontalis sheet carries the forehead above them, and the inner brows
    # pull the glabella between them, so that skin (and its wrinkles' influence) follows
    # the brow bones rather than the head.
    reach: tuple = ()

    @property
    def support(self) -> float:
        """Distance (cm) from the landmark beyond which the bone's weight is 0."""
        return self.radius + max((float(np.hypot(*r)) for r in self.reach), default=0.0)


# Brows: full weight up a 2.5 cm column above each brow bone (and from the inner ones
# down to the glabella's midline), falling off over 3.5 cm around it; the skin within
# FOREHEAD_PIN_CM of the hairline is pinned partly to the head.
_BROW_UP = (0.0, 2.5)
_GLABELLA = (1.05, -0.7)
FOREHEAD_PIN_CM, FOREHEAD_PIN_HEAD = 1.4, 0.5


# (name, landmark, skinning radius). "_R" = subject's right (-x).
BONES = [
    BoneSpec("head", -1, 0.0, "head"),
    BoneSpec("brow_inner_R", BROW_RIGHT[0], 3.5, "brow_R", (_BROW_UP, _GLABELLA)),
    BoneSpec("brow_mid_R", BROW_RIGHT[1], 3.5, "brow_R", (_BROW_UP,)),
    BoneSpec("brow_outer_R", BROW_RIGHT[2], 3.5, "brow_R", (_BROW_UP,)),
    BoneSpec("brow_inner_L", BROW_LEFT[0], 3.5, "brow_L", (_BROW_UP, _GLABELLA)),
    BoneSpec("brow_mid_L", BROW_LEFT[1], 3.5, "brow_L", (_BROW_UP,)),
    BoneSpec("brow_outer_L", BROW_LEFT[2], 3.5, "brow_L", (_BROW_UP,)),
    BoneSpec("eyelid_upper_R", LIDS_RIGHT[0], 1.2, "eye_R"), BoneSpec("eyelid_lower_R", LIDS_RIGHT[1], 1.2, "eye_R"),
    BoneSpec("eyelid_upper_L", LIDS_LEFT[0], 1.2, "eye_L"), BoneSpec("eyelid_lower_L", LIDS_LEFT[1], 1.2, "eye_L"),
    BoneSpec("cheek_R", 205, 3.2, "cheek_R"), BoneSpec("cheek_L", 425, 3.2, "cheek_L"),
    # Below the outer lower lid: rises in a squint or a smile; reaches the crow's feet.
    BoneSpec("cheek_upper_R", 228, 2.6, "eye_R"), BoneSpec("cheek_upper_L", 448, 2.6, "eye_L"),
    BoneSpec("nose_wing_R", 129, 1.6, "cheek_R"), BoneSpec("nose_wing_L", 358, 1.6, "cheek_L"),
    BoneSpec("lip_upper_R", 82, 1.4, "lip_upper"), BoneSpec("lip_upper_C", LIP_GAP[0], 1.4, "lip_upper"),
    BoneSpec("lip_upper_L", 312, 1.4, "lip_upper"),
    BoneSpec("mouth_corner_R", MOUTH_CORNERS[0], 1.6, ""), BoneSpec("mouth_corner_L", MOUTH_CORNERS[1], 1.6, ""),
    BoneSpec("lip_lower_R", 87, 1.4, "lip_lower"), BoneSpec("lip_lower_C", LIP_GAP[1], 1.4, "lip_lower"),
    BoneSpec("lip_lower_L", 317, 1.4, "lip_lower"),
    BoneSpec("jaw", 152, 8.5, "lip_lower"),
]

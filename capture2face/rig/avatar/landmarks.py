"""Eye, lip and brow contours of MediaPipe's canonical face mesh (landmark ids) that the
default avatar's builder, skinning and morphs follow."""

from capture2face.topology import (
    EYE_CORNERS_LEFT,
    EYE_CORNERS_RIGHT,
    LIDS_LEFT,
    LIDS_RIGHT,
    LIP_INNER_CORNERS,
    LIP_INNER_LOWER,
    LIP_INNER_UPPER,
)

__all__ = ["BROW_INNER_R", "BROW_OUTER_R", "BROW_R", "EYE_RINGS", "LIP_INNER_CORNERS", "LIP_LOWER_LINES",
           "LIP_UPPER_LINES"]

EYE_RINGS = {  # side: (outer corner, inner corner, upper-lid landmark)
    "R": (*EYE_CORNERS_RIGHT, LIDS_RIGHT[0]),
    "L": (*EYE_CORNERS_LEFT, LIDS_LEFT[0]),
}
LIP_UPPER_LINES = [61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291,
                   76, 184, 74, 73, 72, 11, 302, 303, 304, 408, 306,
                   62, 183, 42, 41, 38, 12, 268, 271, 272, 407, 292,
                   *LIP_INNER_UPPER]
LIP_LOWER_LINES = [146, 91, 181, 84, 17, 314, 405, 321, 375,
                   77, 90, 180, 85, 16, 315, 404, 320, 307,
                   96, 89, 179, 86, 15, 316, 403, 319, 325,
                   *LIP_INNER_LOWER]
BROW_R = [70, 63, 105, 66, 107, 46, 53, 52, 65, 55]
BROW_INNER_R = [107, 66, 55, 65]
BROW_OUTER_R = [70, 63, 46, 53]

"""The face's topology: MediaPipe Face Landmarker's landmark indices and ARKit's names.

One home for every landmark index the code measures or weighs, so a pair is named once
(``IOD_PAIR``, ``LIP_GAP``, ...) and read everywhere. "Right" and "left" are the
subject's (MediaPipe's convention: the right eye has the lower x). Each pair is
(right or upper, left or lower) as listed. Plain tuples: callers that index arrays with a
set of landmarks wrap them in ``np.array`` where they need fancy indexing.

The contours are the vertex sets of MediaPipe's ``FaceLandmarksConnections``
(``mediapipe.tasks.python.vision``; ``FACEMESH_*`` in the legacy solutions), written out
here because importing mediapipe costs a second or two; tests/test_topology.py checks them
against mediapipe's own.
"""

from __future__ import annotations

# Landmark counts: the canonical face mesh's vertices, then the two irises' five each.
N_MESH = 468
N_LANDMARKS = 478

# Irises: centre, then four rim points; the centres.
IRIS_RIGHT = tuple(range(468, 473))
IRIS_LEFT = tuple(range(473, 478))
IRIS_CENTRES = (IRIS_RIGHT[0], IRIS_LEFT[0])

# The eyes' corners: outer (right, left), inner (right, left); each eye's (outer, inner).
EYE_OUTER_CORNERS = (33, 263)
EYE_INNER_CORNERS = (133, 362)
EYE_CORNERS_RIGHT = (EYE_OUTER_CORNERS[0], EYE_INNER_CORNERS[0])
EYE_CORNERS_LEFT = (EYE_OUTER_CORNERS[1], EYE_INNER_CORNERS[1])
# The inter-ocular distance (outer eye corners): the face's size, the unit of most measures.
IOD_PAIR = EYE_OUTER_CORNERS

# The lids' middles (upper, lower): each eye's opening.
LIDS_RIGHT = (159, 145)
LIDS_LEFT = (386, 374)
# The inner lips' middles (upper, lower): the mouth's opening.
LIP_GAP = (13, 14)
# The mouth's corners (right, left): its width.
MOUTH_CORNERS = (61, 291)
# Each brow's inner, middle and outer points (right, then left).
BROW_RIGHT = (107, 105, 70)
BROW_LEFT = (336, 334, 300)
# Brow height: each brow's middle against its eye's outer corner (right, left).
BROW_HEIGHT_PAIRS = ((BROW_RIGHT[1], EYE_OUTER_CORNERS[0]), (BROW_LEFT[1], EYE_OUTER_CORNERS[1]))

# Contours. The inner lips: the corners (right, left), the lower lip and the upper lip from
# right to left (13 and 14 in their middles).
LIP_INNER_CORNERS = (78, 308)
LIP_INNER_UPPER = (191, 80, 81, 82, 13, 312, 311, 310, 415)
LIP_INNER_LOWER = (95, 88, 178, 87, 14, 317, 402, 318, 324)
LIPS_INNER = (LIP_INNER_CORNERS[0], *LIP_INNER_LOWER, LIP_INNER_CORNERS[1], *LIP_INNER_UPPER)
LIPS_OUTER = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 185, 40, 39, 37, 0, 267, 269, 270, 409)
# The lids without the eye's corners, from the outer corner's side to the inner's.
LID_UPPER_RIGHT = (246, 161, 160, 159, 158, 157, 173)
LID_LOWER_RIGHT = (7, 163, 144, 145, 153, 154, 155)
LID_UPPER_LEFT = (466, 388, 387, 386, 385, 384, 398)
LID_LOWER_LEFT = (249, 390, 373, 374, 380, 381, 382)
# Each eye's whole contour: outer corner, lower lid, inner corner, upper lid.
EYE_RIGHT = (EYE_CORNERS_RIGHT[0], *LID_LOWER_RIGHT, EYE_CORNERS_RIGHT[1], *LID_UPPER_RIGHT)
EYE_LEFT = (EYE_CORNERS_LEFT[0], *LID_LOWER_LEFT, EYE_CORNERS_LEFT[1], *LID_UPPER_LEFT)
# Both brows' contours (left, then right, as MediaPipe lists them).
BROWS = (276, 283, 282, 295, 285, 300, 293, 334, 296, 336, 46, 53, 52, 65, 55, 70, 63, 105, 66, 107)
# The nose's wings (what a sneer moves).
NOSE_WINGS = (48, 64, 98, 102, 240, 278, 294, 327, 331, 460)
# The chin's points below the lower lip.
CHIN = (152, 148, 176, 377, 400)
# The face's silhouette (MediaPipe's face oval), sorted.
FACE_OVAL = (10, 21, 54, 58, 67, 93, 103, 109, 127, 132, 136, 148, 149, 150, 152, 162, 172, 176,
             234, 251, 284, 288, 297, 323, 332, 338, 356, 361, 365, 377, 378, 379, 389, 397, 400, 454)

#: Apple's 52 ARKit blendshapes (MediaPipe has the same names, less ``tongueOut``).
ARKIT_NAMES = [
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight",
    "eyeLookDownLeft", "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft",
    "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight",
    "eyeWideLeft", "eyeWideRight", "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthFrownLeft", "mouthFrownRight", "mouthFunnel",
    "mouthLeft", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight",
    "mouthPucker", "mouthRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower",
    "mouthShrugUpper", "mouthSmileLeft", "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthUpperUpLeft", "mouthUpperUpRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
]
#: MediaPipe's blendshape categories in output order (index 0 "_neutral" is a bias term).
BLENDSHAPE_NAMES = ["_neutral", *(n for n in ARKIT_NAMES if n != "tongueOut")]

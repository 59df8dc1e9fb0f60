"""An eye whose landmarks the front view cast off its lids, placed as the mirror image of
the other eye's on a head that is mirror-symmetric there.

Ready Player Me's XR template: the tracker read its left eye's lower lid 0.8 cm behind the
lid (on the socket's inner skin) and its outer corner (263) 0.5 cm in front of the
right's mirror image, on the upper lid; its blink closes the lids' landmarks to 0.73 of
their rest distance, and the corner, moving with every blink and look, read as the brow's
rise (the brow's measure is its height above that corner). Its right eye passes the
load-time check (:func:`capture2face.measures.landmark_faults`) and its mesh is
symmetric to 0.001 inter-ocular distances around the eyes. So each of the failing eye's
contour landmarks (:data:`~capture2face.topology.EYE_LEFT` or ``EYE_RIGHT``, corners
included) takes the other eye's corresponding landmark's triangle, each vertex replaced by
its mirror image, with the same barycentric weights. Kept only where the mirrored triangles'
vertices have skin vertices at their mirror images (:data:`MIRROR_TOL_IOD`) and the eye
then passes the check.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from capture2face.character.landmarks import skin_vertices
from capture2face.measures import landmark_faults
from capture2face.rig.face_rig import FaceRig, landmark_points
from capture2face.runtime.log import log
from capture2face.topology import EYE_LEFT, EYE_RIGHT

#: MediaPipe landmarks on the face's midline (the nose's ridge and tip, the lips' and chin's
#: middles, the forehead's): their median x is the mirror plane.
MIDLINE = (1, 2, 4, 5, 6, 8, 9, 10, 151, 168, 195, 197, 0, 13, 14, 17, 152)
#: Each eye's contour, in corresponding order (the mirror of EYE_RIGHT[k] is EYE_LEFT[k]).
EYES = {"eye_right": np.array(EYE_RIGHT), "eye_left": np.array(EYE_LEFT)}
#: The eye's vertices' mirror images must have skin vertices this near (median,
#: inter-ocular distances): the XR head's 0.0003 about the plane found in
#: :data:`MIRROR_ROUNDS` rounds (0.008 about the midline landmarks' plane).
MIRROR_TOL_IOD, MIRROR_ROUNDS = 0.005, 3


def mirrored_eyes(rig: FaceRig, faces: np.ndarray, bary: np.ndarray, vertices: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(faces, bary, vertices) of the landmarks (``FaceRig.landmark_faces`` and its
    siblings) with the eye that fails the load-time check, where the other passes, placed
    as the mirror image of the other's (module docs); as given otherwise."""
    def faults(f, b, v) -> dict[str, str]:
        return landmark_faults(rig.replace(landmark_faces=f, landmark_bary=b, landmark_vertices=v))

    found = faults(faces, bary, vertices)
    bad = [m for m in EYES if m in found]
    if len(bad) != 1:
        return faces, bary, vertices
    good = EYES["eye_left" if bad[0] == "eye_right" else "eye_right"]
    src = faces[good]
    if (src < 0).any():
        return faces, bary, vertices
    verts = np.asarray(rig.vertices, np.float64)
    skin = np.flatnonzero(skin_vertices(rig))
    tree, at = cKDTree(verts[skin]), verts[src.ravel()]
    placed = rig.replace(landmark_faces=faces, landmark_bary=bary, landmark_vertices=vertices)
    mid = float(np.median(landmark_points(placed, verts, list(MIDLINE))[:, 0]))
    for _ in range(MIRROR_ROUNDS):  # the plane from the mesh: the landmarks' midline is off by a millimetre
        dist, idx = tree.query(at * np.array([-1.0, 1.0, 1.0]) + np.array([2.0 * mid, 0.0, 0.0]))
        mid = float(np.median(at[:, 0] + verts[skin[idx], 0])) / 2.0
    if float(np.median(dist)) > MIRROR_TOL_IOD * placed.interocular():
        return faces, bary, vertices
    out_f, out_b, out_v = faces.copy(), bary.copy(), vertices.copy()
    rows = EYES[bad[0]]
    out_f[rows] = skin[idx].reshape(src.shape)
    out_b[rows] = bary[good]
    out_v[rows] = out_f[rows, np.argmax(out_b[rows], 1)]
    if bad[0] in faults(out_f, out_b, out_v):
        return faces, bary, vertices
    log.info("character '%s': its %s eye's landmarks are placed as the mirror image of the other's (the front "
             "view cast them off its lids: %s)", rig.name, bad[0].removeprefix("eye_"), found[bad[0]])
    return out_f, out_b, out_v

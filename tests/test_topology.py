"""capture2face.topology: the indices and names are MediaPipe's and ARKit's own."""

import numpy as np
import pytest

from capture2face import topology as T
from capture2face.io.video_input import iter_frames
from capture2face.models.face_model import find_face_model
from tests.helpers import shared_clip

connections = pytest.importorskip("mediapipe.tasks.python.vision").FaceLandmarksConnections


def _vertices(edges) -> set[int]:
    return {i for c in edges for i in (c.start, c.end)}


def test_contours_are_mediapipes():
    assert set(T.FACE_OVAL) == _vertices(connections.FACE_LANDMARKS_FACE_OVAL)
    assert list(T.FACE_OVAL) == sorted(set(T.FACE_OVAL))
    assert set(T.LIPS_OUTER + T.LIPS_INNER) == _vertices(connections.FACE_LANDMARKS_LIPS)
    assert set(T.EYE_RIGHT) == _vertices(connections.FACE_LANDMARKS_RIGHT_EYE)
    assert set(T.EYE_LEFT) == _vertices(connections.FACE_LANDMARKS_LEFT_EYE)
    brows = _vertices(connections.FACE_LANDMARKS_RIGHT_EYEBROW) | _vertices(connections.FACE_LANDMARKS_LEFT_EYEBROW)
    assert set(T.BROWS) == brows
    assert set(T.IRIS_RIGHT[1:]) == _vertices(connections.FACE_LANDMARKS_RIGHT_IRIS)
    assert set(T.IRIS_LEFT[1:]) == _vertices(connections.FACE_LANDMARKS_LEFT_IRIS)
    for contour in (T.LIPS_OUTER, T.LIPS_INNER, T.EYE_RIGHT, T.EYE_LEFT, T.BROWS, T.NOSE_WINGS, T.FACE_OVAL):
        assert len(set(contour)) == len(contour)


def test_named_points_lie_on_their_contours():
    assert set(T.EYE_CORNERS_RIGHT + T.LIDS_RIGHT) <= set(T.EYE_RIGHT)
    assert set(T.EYE_CORNERS_LEFT + T.LIDS_LEFT) <= set(T.EYE_LEFT)
    assert T.IOD_PAIR == (T.EYE_CORNERS_RIGHT[0], T.EYE_CORNERS_LEFT[0]) == (33, 263)
    assert set(T.LIP_GAP) <= set(T.LIPS_INNER) and set(T.MOUTH_CORNERS) <= set(T.LIPS_OUTER)
    assert (T.LIP_INNER_UPPER[4], T.LIP_INNER_LOWER[4]) == T.LIP_GAP
    assert set(T.BROW_RIGHT + T.BROW_LEFT) <= set(T.BROWS)
    assert all(brow in T.BROWS and corner in T.IOD_PAIR for brow, corner in T.BROW_HEIGHT_PAIRS)
    assert T.IRIS_CENTRES == (468, 473) and T.IRIS_LEFT[-1] == T.N_LANDMARKS - 1
    assert max(T.FACE_OVAL + T.LIPS_OUTER + T.EYE_LEFT + T.BROWS + T.NOSE_WINGS + T.CHIN) < T.N_MESH


def test_arkit_names_are_the_trackers():
    assert len(T.ARKIT_NAMES) == 52 == len(set(T.ARKIT_NAMES))
    assert T.BLENDSHAPE_NAMES[0] == "_neutral"
    assert set(T.ARKIT_NAMES) - set(T.BLENDSHAPE_NAMES) == {"tongueOut"}
    assert [n for n in T.ARKIT_NAMES if n in T.BLENDSHAPE_NAMES] == T.BLENDSHAPE_NAMES[1:]


def test_blendshape_names_are_the_models():
    """The bundled model's blendshape categories, in its output order, on a real face."""
    import mediapipe as mp
    from mediapipe.tasks.python import BaseOptions, vision

    rgb = next(iter_frames(shared_clip("d0.mp4"), max_frames=1))[1]
    options = vision.FaceLandmarkerOptions(base_options=BaseOptions(model_asset_path=str(find_face_model(None))),
                                           output_face_blendshapes=True, num_faces=1)
    with vision.FaceLandmarker.create_from_options(options) as landmarker:
        result = landmarker.detect(mp.Image(image_format=mp.ImageFormat.SRGB, data=np.ascontiguousarray(rgb)))
    assert [c.category_name for c in result.face_blendshapes[0]] == T.BLENDSHAPE_NAMES
    assert len(result.face_landmarks[0]) == T.N_LANDMARKS


def test_old_homes_keep_working():
    from capture2face.rig.arkit_names import ARKIT_NAMES
    from capture2face.tracking import BLENDSHAPE_NAMES, N_LANDMARKS
    from capture2face.tracking.landmarker import BLENDSHAPE_NAMES as LANDMARKER_NAMES
    from capture2face.tracking.rest import IOD_PAIR

    assert ARKIT_NAMES is T.ARKIT_NAMES and BLENDSHAPE_NAMES is LANDMARKER_NAMES is T.BLENDSHAPE_NAMES
    assert N_LANDMARKS == T.N_LANDMARKS and IOD_PAIR is T.IOD_PAIR

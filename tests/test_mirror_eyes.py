"""An eye whose landmarks the front view cast off its lids takes the other eye's mirror
image on a symmetric head (issue 31: Ready Player Me's XR head's left eye)."""

from __future__ import annotations

import numpy as np
import pytest

from capture2face.character.mirror_eyes import mirrored_eyes
from capture2face.measures import landmark_faults
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import landmark_points
from capture2face.topology import EYE_LEFT, EYE_RIGHT, LID_LOWER_LEFT
from tests.helpers import shared_character


@pytest.fixture(scope="module")
def cast():
    """The built-in avatar (mirror-symmetric) with its landmarks as cast ones (a vertex each)
    and its left eye's lower lid cast onto the glabella, as the XR head's was cast behind the
    lid: its blink no longer closes 386-374."""
    rig = default_avatar()
    lv = np.asarray(rig.landmark_vertices, np.int32)
    rig = rig.replace(landmark_faces=np.repeat(lv[:, None], 3, 1),
                      landmark_bary=np.tile(np.float32([1, 0, 0]), (len(lv), 1)))
    assert not landmark_faults(rig)
    faces, vertices = rig.landmark_faces.copy(), lv.copy()
    faces[list(LID_LOWER_LEFT)] = lv[9]
    vertices[list(LID_LOWER_LEFT)] = lv[9]
    return rig, faces, rig.landmark_bary.copy(), vertices


def test_an_eye_cast_off_its_lids_takes_the_other_eyes_mirror_image(cast):
    rig, faces, bary, vertices = cast
    assert "eye_left" in landmark_faults(rig.replace(landmark_faces=faces, landmark_vertices=vertices))
    f, b, v = mirrored_eyes(rig, faces, bary, vertices)
    placed = rig.replace(landmark_faces=f, landmark_bary=b, landmark_vertices=v)
    assert not landmark_faults(placed)
    pts = landmark_points(placed, np.asarray(rig.vertices, np.float64))
    mirror = pts[list(EYE_RIGHT)] * np.array([-1.0, 1.0, 1.0])
    assert np.abs(pts[list(EYE_LEFT)] - mirror).max() < 0.01 * placed.interocular()
    np.testing.assert_array_equal(f[list(EYE_RIGHT)], faces[list(EYE_RIGHT)])  # the other eye as it was


def test_no_mirror_image_on_an_asymmetric_head_or_where_both_eyes_pass(cast):
    rig, faces, bary, vertices = cast
    verts = np.asarray(rig.vertices).copy()
    verts[verts[:, 0] > 0, 2] += 0.05 * rig.interocular()  # the left half pushed forward
    f, _, _ = mirrored_eyes(rig.replace(vertices=verts), faces, bary, vertices)
    np.testing.assert_array_equal(f, faces)
    good = rig.landmark_faces
    f, _, _ = mirrored_eyes(rig, good, bary, rig.landmark_vertices)
    np.testing.assert_array_equal(f, good)


@pytest.mark.slow
def test_the_xr_heads_left_eye_is_on_its_lids(tmp_path, monkeypatch):
    """Ready Player Me's XR head: its left eye's lids pass the load-time check (its blink
    closed 386-374 to 0.73 of their rest distance), its outer corner 263 sits at the mirror
    image of 33 (0.05 IOD in front of it, on the upper lid, before)."""
    from capture2face.character.load import load_character

    monkeypatch.setenv("CAPTURE2FACE_CACHE", str(tmp_path))
    rig = load_character(shared_character("rpm_male_xr_template_arkit52.glb"))
    assert rig.landmark_source == "tracker front view" and not landmark_faults(rig)
    pts = landmark_points(rig, np.asarray(rig.vertices, np.float64))
    mid = 0.5 * (pts[33, 0] + pts[263, 0])
    corner = pts[33] * np.array([-1.0, 1.0, 1.0]) + np.array([2.0 * mid, 0.0, 0.0])
    assert np.abs(corner - pts[263]).max() < 0.01 * rig.interocular()

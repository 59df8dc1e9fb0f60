"""Every character's landmarks, found before and apart from its automatic wrinkles (issue 31
item 2): the tracker's front view where it reads the face, else what the character's own
morphs move (an anime VRM); a head whose wrinkle bake fails keeps them; report.json says
how they were found."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import REPO, SAMPLE, rewrite, run_cli

SHARED = Path(os.environ.get("CAPTURE2FACE_SHARED_CHARACTERS", REPO.parent / "shared" / "characters"))
GODETTE = SHARED / "godette_vrm0_presets.vrm"


def _placed(rig, ids) -> bool:
    return bool((np.asarray(rig.landmark_vertices)[list(ids)] >= 0).all())


def _no_uvs(gltf, _binary):
    for mesh in gltf["meshes"]:
        for prim in mesh["primitives"]:
            prim["attributes"].pop("TEXCOORD_0", None)
            prim["attributes"].pop("TANGENT", None)


@pytest.mark.slow
def test_a_head_whose_wrinkles_cannot_be_baked_keeps_its_landmarks(hero, tmp_path):
    """No UVs: the face covers no texel, so no wrinkle maps; the tracker's landmarks stay,
    so every measured landmark has a place (eval fidelity --character works)."""
    from capture2face.character.load import load_character
    from capture2face.measures import MEASURED
    from capture2face.rig.arkit_names import drive_mode, is_automatic

    rig = load_character(rewrite(hero, tmp_path / "nouvs.glb", _no_uvs))
    assert not is_automatic(rig)  # no wrinkle influences
    assert drive_mode(rig) == "arkit"  # its landmarks measure; the ARKit curves still drive it
    assert rig.landmark_source == "tracker front view"
    assert rig.landmark_faces is not None and _placed(rig, MEASURED)


@pytest.mark.slow
@pytest.mark.skipif(not GODETTE.is_file(), reason="the shared characters are not here")
def test_an_anime_face_gets_its_landmarks_from_its_morphs():
    """Godette (VRoid, presets only): the tracker cannot read it; its landmarks come from
    its presets, on the right parts: ``A`` parts the inner lips, ``Blink_L/R`` close the lids."""
    from capture2face.character.landmarks import pose_weights
    from capture2face.character.load import load_character
    from capture2face.measures import MEASURED, MEASURES
    from capture2face.rig.face_rig import landmark_points

    rig = load_character(GODETTE)
    assert rig.landmark_source == "morphs"
    assert int((rig.landmark_vertices >= 0).sum()) >= 468
    assert _placed(rig, MEASURED)
    rest = rig.vertices.astype(np.float64)
    iod = rig.interocular()

    def gap(names, pair):
        moved = rest + np.einsum("m,mvc->vc", pose_weights(rig, names), rig.morph_positions)
        a, b = landmark_points(rig, moved, list(pair))
        a0, b0 = landmark_points(rig, rest, list(pair))
        return np.linalg.norm(a0 - b0), np.linalg.norm(a - b)

    before, after = gap(["jawOpen"], MEASURES["mouth_open"])
    assert after - before > 0.05 * iod, (before, after, iod)
    for side, eye in (("Left", "eye_left"), ("Right", "eye_right")):
        before, after = gap([f"eyeBlink{side}"], MEASURES[eye])
        assert after < 0.5 * before, (side, before, after)


@pytest.mark.slow
@pytest.mark.skipif(not GODETTE.is_file(), reason="the shared characters are not here")
def test_report_names_how_the_landmarks_were_found(tmp_path):
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(GODETTE), "--size", "64",
                 timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads((tmp_path / "out" / "sample" / "report.json").read_text())
    assert report["character_landmarks"]["source"] == "morphs"
    assert report["character_landmarks"]["found"] >= 468


def test_a_character_with_found_landmarks_is_framed_on_its_face():
    """The visemes-only Ready Player Me (a whole body, its landmarks read by the tracker, no
    automatic wrinkles): the camera frames its face, not the body (avatar.mp4 showed the
    whole figure, and the tracked-back figures found no face)."""
    from capture2face.camera import face_centre_and_height
    from capture2face.character.load import load_character

    path = SHARED / "rpm_male_goatee_glasses_visemes_only.glb"
    if not path.is_file():
        pytest.skip(f"{path} not present")
    rig = load_character(path)
    assert rig.landmark_source == "tracker front view"
    _, height = face_centre_and_height(rig)
    assert height < 2.5 * rig.interocular()  # a face (about 1.7 IOD), not a body (about 20)

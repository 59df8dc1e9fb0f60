"""Faces the tracker cannot read (anime VRM heads): eyes from VRM's humanoid eye bones,
wrinkles only on the head's skin and 0 at the actor's rest, and the posed-landmark
figures ``eval characters`` judges them on (capture2face.eval.posed)."""

from __future__ import annotations

import numpy as np
import pytest

from capture2face.gltf.container import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GlbBuilder
from tests.helpers import shared_character, synthetic_track

EYE_R, EYE_L = (-0.03, 1.5, 0.05), (0.03, 1.5, 0.05)  # VRM 0.x scene (metres, facing -z)


def _quad(centre, size=0.01):
    x, y, z = centre
    return np.array([[x - size, y - size, z], [x + size, y - size, z], [x - size, y + size, z],
                      [x + size, y + size, z]], np.float32)


def _vrm0_with_eye_bones(path):
    """A VRM 0.x head: a face quad on the head joint with one morph (preset A), and two eye
    quads, each skinned to its humanoid eye bone (rightEye node 1, leftEye node 2)."""
    bld = GlbBuilder()
    pos = np.concatenate([_quad((0, 1.45, 0.06), 0.05), _quad(EYE_R), _quad(EYE_L)])
    joints = np.repeat(np.array([[0, 0, 0, 0], [1, 0, 0, 0], [2, 0, 0, 0]], np.uint8), 4, 0)
    weights = np.tile(np.array([[1, 0, 0, 0]], np.float32), (12, 1))
    tri = np.array([0, 1, 2, 2, 1, 3], np.uint16)
    delta = np.zeros_like(pos)
    delta[:2, 1] = -0.01  # A lowers the face quad's bottom edge
    ibm = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    for k, t in enumerate([(0, 1.4, 0), EYE_R, EYE_L]):
        ibm[k, 3, :3] = -np.asarray(t)  # column-major: the translation is the last column
    bld.add("meshes", {"primitives": [{
        "attributes": {"POSITION": bld.accessor(pos, ARRAY_BUFFER, minmax=True),
                       "JOINTS_0": bld.accessor(joints, ARRAY_BUFFER),
                       "WEIGHTS_0": bld.accessor(weights, ARRAY_BUFFER)},
        "indices": bld.accessor(np.concatenate([tri, tri + 4, tri + 8]).astype(np.uint16), ELEMENT_ARRAY_BUFFER),
        "targets": [{"POSITION": bld.accessor(delta, ARRAY_BUFFER, minmax=True)}]}],
        "extras": {"targetNames": ["ah"]}})
    bld.add("nodes", {"name": "Head", "translation": [0, 1.4, 0], "children": [1, 2]})
    bld.add("nodes", {"name": "RightEye", "translation": [EYE_R[0], EYE_R[1] - 1.4, EYE_R[2]]})
    bld.add("nodes", {"name": "LeftEye", "translation": [EYE_L[0], EYE_L[1] - 1.4, EYE_L[2]]})
    bld.add("nodes", {"name": "Face", "mesh": 0, "skin": 0})
    bld.add("skins", {"joints": [0, 1, 2], "inverseBindMatrices": bld.accessor(ibm.reshape(-1, 16), None)})
    bld.gltf["scenes"] = [{"nodes": [0, 3]}]
    bld.gltf["extensionsUsed"] = ["VRM"]
    bld.gltf["extensions"] = {"VRM": {
        "humanoid": {"humanBones": [{"bone": "head", "node": 0}, {"bone": "rightEye", "node": 1},
                                    {"bone": "leftEye", "node": 2}]},
        "blendShapeMaster": {"blendShapeGroups": [
            {"name": "A", "presetName": "a", "binds": [{"mesh": 0, "index": 0, "weight": 100}]}]}}}
    path.write_bytes(bld.to_bytes())
    return path


def test_vrm_eye_bones_give_its_eye_centres(tmp_path):
    from capture2face.character.landmark_sources import eye_facts
    from capture2face.gltf.rig_import import import_glb
    from capture2face.gltf.vrm import VRM_EYE_BONES

    rig = import_glb(_vrm0_with_eye_bones(tmp_path / "c.vrm"))
    assert rig.has_eyes and rig.eye_source == VRM_EYE_BONES
    # VRM 0.x is turned to face +z: x and z change sign; metres -> cm. Row 0: its right eye.
    turn = np.array([-100.0, 100.0, -100.0])
    np.testing.assert_allclose(rig.eye_centres, [np.multiply(EYE_R, turn), np.multiply(EYE_L, turn)], atol=1e-4)
    assert rig.eye_vertex_side.tolist() == [-1] * 4 + [0] * 4 + [1] * 4
    assert eye_facts(rig) == {"turn": "eyeballs", "centres": VRM_EYE_BONES}


def test_vrm_eye_bones_give_way_to_its_look_expressions_where_it_says_so(tmp_path):
    from capture2face.gltf.container import GlbReader
    from capture2face.gltf.rig_import import import_glb
    from tests.helpers import rewrite

    src = _vrm0_with_eye_bones(tmp_path / "c.vrm")
    assert GlbReader(src).gltf["extensions"]["VRM"].get("firstPerson") is None  # Bone by default
    turned = rewrite(src, tmp_path / "d.vrm",
                     lambda g, _: g["extensions"]["VRM"].update(firstPerson={"lookAtTypeName": "BlendShape"}))
    assert not import_glb(turned).has_eyes


def test_a_vrm_without_eye_bones_turns_its_eyes_by_its_look_presets():
    from capture2face.character.landmark_sources import eye_facts
    from capture2face.character.load import load_character

    rig = load_character(shared_character("godette_vrm0_presets.vrm"))
    assert not rig.has_eyes  # Godette's humanoid has no eye bones
    assert eye_facts(rig) == {"turn": "morphs", "centres": "none",
                              "morphs": ["lookup", "lookdown", "lookleft", "lookright"]}


@pytest.fixture(scope="module")
def godette_performs():
    from capture2face.character.load import load_character
    from capture2face.retarget import retarget

    rig = load_character(shared_character("godette_vrm0_presets.vrm"))
    track, _ = synthetic_track()
    return rig, track, retarget(track, rig)


def test_godettes_wrinkles_stay_on_its_face_and_rest_with_the_actor(godette_performs):
    from capture2face.rig.influences import vertex_influences

    rig, track, anim = godette_performs
    assert rig.landmark_source == "morphs"
    assert np.abs(anim.influences[track.neutral_frame]).max() < 1e-6  # 0 at the actor's rest
    assert anim.influences.max() > 0.3  # and there when the actor frowns / opens the mouth
    reach = vertex_influences(anim.influences.max(0, keepdims=True), rig.dense_skin_weights())[0].max(0) > 1e-3
    chin = rig.vertices[rig.landmark_vertices[[13, 14]], 1].min()
    # Never on the collar or chest (on the neck and chest joints, not the head's).
    assert reach.any() and not (reach & (rig.head_weights < 0.5)).any()
    assert rig.vertices[reach, 1].min() > chin - 0.5 * rig.interocular()


def test_posed_landmark_figures_of_a_face_the_tracker_cannot_read(godette_performs, monkeypatch):
    from capture2face.eval import posed
    from capture2face.rig.avatar import default_avatar

    rig, track, anim = godette_performs
    truth = synthetic_track()[1]
    actor = np.zeros((track.n_frames, 6))  # the actor's measures (the synthetic track has no pixels)
    actor[:, 0] = 0.4 * truth["jawOpen"]
    actor[:, 4] = -0.9 * truth["eyeBlinkRight"]
    actor[:, 2:4] = 0.1 * truth["browInnerUp"][:, None]
    monkeypatch.setattr(posed, "source_measures", lambda _: actor)
    figures = posed.posed_follow(track, anim, rig)
    assert figures["measured_by"] == posed.MEASURE
    # (the eyes less: Sorrow, which the inner brows' raise drives, lowers Godette's lids)
    assert figures["mouth_open_r"] > 0.9 and figures["eyes_r"] > 0.5
    # Its mouth's whole range is a fraction of a human's: the range gain stretches it.
    assert 0 < figures["mouth_open_range"] < 0.6
    assert figures["mouth_open_range_gain"] == pytest.approx(figures["mouth_open_gain"] / figures["mouth_open_range"],
                                                             rel=1e-3)
    assert np.isnan(figures["brows_r"]) and figures["brows_range"] == 0  # no morph moves its brows
    assert posed.measure_ranges(default_avatar())[0] == pytest.approx(0.213, abs=0.01)  # jawOpen's 13-14, IODs


def test_goals_judge_the_posed_figures_where_the_tracker_cannot_read_the_face():
    from capture2face.eval import characters

    nan = float("nan")
    shading = {"mouth_open_r": 0.0, "mouth_open_gain": 0.1, "eyes_r": 0.1, "eyes_gain": 0.1, "brows_r": 0.1,
               "brows_gain": 0.1, "darkening_p95_mean": 0.01}
    posed = {"mouth_open_r": 0.9, "mouth_open_range_gain": 0.8, "eyes_r": 0.85, "eyes_range_gain": 0.9,
             "brows_r": nan, "brows_range_gain": nan}
    row = {"shading": shading, "posed": posed, "fidelity": {"judged": 0, "faithful": 0},
           "follow_by": characters.POSED}
    # no darkening goal: its discs would lie where the tracker guesses on a face it cannot read
    assert characters.goals_met(row) == {"mouth_open": True, "eyes": True}
    row["follow_by"] = characters.TRACKED
    met = characters.goals_met(row)
    assert met["mouth_open"] is False and met["darkening"] is True


def test_the_landmark_check_at_load_judges_convention_heads_by_their_presets(godette_performs):
    from capture2face.measures import landmark_faults

    rig = godette_performs[0]
    assert landmark_faults(rig) == {}  # its presets A + O open 13-14, Blink_L / _R close the lids
    faces, bary = rig.landmark_faces.copy(), rig.landmark_bary.copy()
    faces[14], bary[14] = faces[13], bary[13]  # the lower lip's landmark on the upper lip
    faults = landmark_faults(rig.replace(landmark_faces=faces, landmark_bary=bary))
    assert set(faults) == {"mouth_open"} and "jawOpen opens landmarks 13-14" in faults["mouth_open"]

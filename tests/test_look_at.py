"""A VRM's look presets turned by its own lookAt range tables (gltf.vrm.look_ranges,
rig.look_at)."""

import numpy as np
import pytest

from capture2face.gltf.vrm import look_ranges
from capture2face.rig.look_at import look_weights


def _vrm0(first_person: dict) -> dict:
    return {"extensions": {"VRM": {"firstPerson": first_person}}}


def test_vrm0_curves_are_read_and_start_at_zero():
    fp = {"lookAtTypeName": "BlendShape",
          "lookAtHorizontalOuter": {"curve": [0, 0.05, 0, 0, 1, 1.05, 1, 1], "xRange": 90, "yRange": 2.0},
          "lookAtVerticalDown": {"xRange": 30, "yRange": 1.0},  # no curve: linear
          "lookAtVerticalUp": {"curve": [0, 0, 0, 1, 1, 1, 1, 0], "xRange": 60, "yRange": 0.5}}
    table = look_ranges(_vrm0(fp))
    assert table.shape == (3, 91)
    assert np.all(table[:, 0] == 0)  # straight ahead turns no look preset
    assert table[1, 15] == pytest.approx(0.5) and table[1, 30] == pytest.approx(1.0)
    assert table[2, 60] == pytest.approx(0.5) and table[2, 90] == pytest.approx(0.5)  # held past xRange
    assert np.all(np.diff(table[0]) >= -1e-6) and table[0, 90] == pytest.approx(1.0)  # clipped to 1


def test_bone_lookat_and_vrm1_ranges():
    assert look_ranges(_vrm0({"lookAtTypeName": "Bone"})) is None
    assert look_ranges({"asset": {}}) is None
    vrm1 = {"extensions": {"VRMC_vrm": {"lookAt": {"type": "expression",
                                                   "rangeMapVerticalDown": {"inputMaxValue": 20, "outputScale": 1}}}}}
    table = look_ranges(vrm1)
    assert table[1, 10] == pytest.approx(0.5) and table[1, 20] == pytest.approx(1.0)
    assert table[0, 45] == pytest.approx(0.5)  # defaults: 90 degrees to 1


def test_look_weights_follow_the_gaze_sides():
    table = np.tile(np.linspace(0, 1, 91), (3, 1)).astype(np.float32)
    names = ["A", "LookUp", "LookDown", "LookLeft", "LookRight"]
    gaze = np.zeros((3, 2, 2), np.float32)
    gaze[0, :, 0] = 45.0  # yaw towards the character's own left
    gaze[1, :, 1] = 18.0  # pitch down
    gaze[2, :, 1] = -9.0  # up
    w = look_weights(np.full((3, 5), 0.3, np.float32), names, table, gaze)
    assert w[:, 0].tolist() == pytest.approx([0.3] * 3)  # other morphs kept
    assert w[0, 3] == pytest.approx(0.5) and w[0, 4] == 0 and w[0, 1] == 0 and w[0, 2] == 0
    assert w[1, 2] == pytest.approx(0.2) and w[2, 1] == pytest.approx(0.1) and w[2, 2] == 0
    assert look_weights(w, names, None, gaze) is w and look_weights(w, names, table, None) is w


def test_godettes_own_tables():
    import json
    import struct

    from tests.helpers import shared_character

    data = shared_character("godette_vrm0_presets.vrm").read_bytes()
    table = look_ranges(json.loads(data[20:20 + struct.unpack("<I", data[12:16])[0]]))
    # Its down map is linear to 1 at 23 degrees (3.9 / 90), up a slow curve (2.9 / 90).
    assert table[1, 23] == pytest.approx(1.0, abs=0.01) and table[1, 10] == pytest.approx(0.43, abs=0.01)
    assert 0.1 < table[2, 20] < 0.2 and table[0, 0] == 0 and table[0, 45] == pytest.approx(1.0)


def test_godettes_mouth_landmarks_and_opening():
    """Its lips' landmarks on its own small mouth (corners at the ends the vowels move,
    the upper inner lip on the upper lip, not the nose), and the open vowel filled to the
    actor's opening at its range."""
    from capture2face.character.load import load_character
    from capture2face.rig.face_rig import landmark_points
    from capture2face.rig.open_fill import HUMAN_OPEN_IOD, actor_opening, fill_opening, morph_openings
    from tests.helpers import shared_character

    rig = load_character(shared_character("godette_vrm0_presets.vrm"))
    iod = rig.interocular()
    p = landmark_points(rig, rig.vertices, [61, 291, 13, 14])
    assert 0.1 * iod < p[1, 0] - p[0, 0] < 0.2 * iod  # its mouth is 3.6 cm wide, 0.15 eye distances
    assert 0 < p[2, 1] - p[3, 1] < 0.03 * iod  # closed at rest
    opens = dict(zip(rig.morph_names, morph_openings(rig)))
    assert opens["o"] > opens["a"] > opens["u"] > opens["e"] > 0
    a = landmark_points(rig, rig.vertices + rig.morph_positions[rig.morph_names.index("a")], [61, 291])
    assert a[1, 0] - a[0, 0] > p[1, 0] - p[0, 0] + 0.05 * iod  # the open vowel widens it
    w = np.zeros((3, rig.n_morphs), np.float32)
    w[:, rig.morph_names.index("e")] = 1.0  # a spread shape, nearly closed
    filled = fill_opening(w, rig, np.array([0.0, 0.5, 2.0]))
    lips = filled @ morph_openings(rig)
    assert filled[0].tolist() == w[0].tolist()  # the actor's mouth closed: unchanged
    assert lips[1] == pytest.approx(0.5 * max(opens.values()), rel=1e-4)  # half a human's: half its range
    assert filled[2, rig.morph_names.index("a")] == 1.0  # wider than a human's jaw: the open vowel full
    rounded = fill_opening(w, rig, np.full(3, 0.5), np.ones(3))  # rounded lips open by the round vowel
    assert rounded[:, rig.morph_names.index("a")].tolist() == [0.0] * 3
    assert (rounded @ morph_openings(rig)) == pytest.approx(lips[1], rel=1e-4)
    rest = np.zeros((478, 3))
    rest[[33, 263], 0] = [-3.0, 3.0]  # an inter-ocular distance of 6
    lm = np.repeat(rest[None], 2, 0)
    lm[1, 14, 1] = -HUMAN_OPEN_IOD * 6.0
    assert actor_opening(lm, rest) == pytest.approx([0.0, 1.0])


def test_godette_performs_with_its_gaze_tables_and_filled_mouth():
    """Retargeted, its look presets are its tables of the gaze (still eyes: 0) and its mouth
    opens as the actor's: its lips part with the synthetic jaw (r 0.96), at the jaw's peak
    past half its full range (0.59: the actor's mouth narrows as it opens, and past ``O`` every
    vowel that opens this mouth also widens it, rig/mouth_fill.py)."""
    from capture2face.character.load import load_character
    from capture2face.retarget import retarget
    from capture2face.rig.morph_conventions import recipe_poses
    from capture2face.rig.mouth_fill import morph_mouth
    from capture2face.topology import ARKIT_NAMES
    from tests.helpers import shared_character, synthetic_track

    rig = load_character(shared_character("godette_vrm0_presets.vrm"))
    track, truth = synthetic_track()
    w = retarget(track, rig).blend_weights
    looks = [rig.morph_names.index(n) for n in ("lookup", "lookdown", "lookleft", "lookright")]
    assert np.abs(w[:, looks]).max() < 0.05
    parts = morph_mouth(rig)[:, 0]  # (M,) how far each morph at 1 parts its lips
    opening, full = w @ parts, recipe_poses(rig.morph_names)[ARKIT_NAMES.index("jawOpen")] @ parts
    assert np.corrcoef(opening, truth["jawOpen"])[0, 1] > 0.9
    assert opening[int(np.argmax(truth["jawOpen"]))] > 0.5 * full
    assert w[track.neutral_frame, rig.morph_names.index("a")] < 0.05

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

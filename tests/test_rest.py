"""The actor's rest, region by region (capture2face.tracking.rest)."""

import dataclasses

import numpy as np
import pytest

from capture2face.rig.canonical import load_canonical_mesh
from capture2face.topology import BLENDSHAPE_NAMES, IOD_PAIR
from capture2face.tracking.rest import (
    FACE,
    REGIONS,
    actor_rest,
    clip_rest,
    frame_rest,
    landmark_regions,
    rest_fields,
    rest_geometry,
    rest_warnings,
)

F = 100
NAMES = list(BLENDSHAPE_NAMES)
BROWS = [105, 334, 66, 296, 107, 336, 70, 300, 63, 293, 52, 282, 53, 283, 65, 295, 46, 276, 55, 285]


def _face() -> np.ndarray:
    """(478, 3) a canonical face (irises at the eyes' centres)."""
    v = load_canonical_mesh().vertices.astype(np.float32)
    iris = [v[[33, 133, 159, 145]].mean(0)] * 5 + [v[[263, 362, 386, 374]].mean(0)] * 5
    return np.concatenate([v, np.array(iris, np.float32)])


def _clip(brows_raised: np.ndarray, mouth_open: np.ndarray):
    """Landmarks (F, 478, 3) and scores (F, 52) of an actor whose brows rise 0.8 cm and
    whose jaw drops 1.5 cm on the given frames, scored as MediaPipe would."""
    lm = np.repeat(_face()[None], F, 0)
    lm[np.ix_(brows_raised, BROWS, [1])] += 0.8
    lower = np.flatnonzero(_face()[:, 1] < _face()[14, 1] + 0.05)  # the lower lip and the chin
    lm[np.ix_(mouth_open, lower, [1])] -= 1.5
    scores = np.zeros((F, len(NAMES)), np.float32)
    scores[brows_raised, NAMES.index("browInnerUp")] = 0.8
    scores[mouth_open, NAMES.index("jawOpen")] = 0.6
    return lm, scores


def _rest(lm, scores):
    pose = np.tile(np.eye(4, dtype=np.float32), (F, 1, 1))
    return clip_rest(lm, scores, NAMES, pose, np.arange(F) / 30.0, np.ones(F, bool))


def test_each_region_takes_its_own_relaxed_frames():
    """Brows raised on 80 of 100 frames, the mouth open on the other 20: no frame rests
    whole, yet each region's rest is its own calm frames and the rest face carries the
    brows of one and the lips of the other."""
    frames = np.arange(F)
    lm, scores = _clip(brows_raised=frames[:80], mouth_open=frames[80:])
    rest = _rest(lm, scores)
    assert set(rest.frames["brows"]) <= set(range(80, F))
    assert set(rest.frames["mouth"]) <= set(range(80))
    face = _face()
    np.testing.assert_allclose(rest.landmarks[BROWS], face[BROWS], atol=1e-5)  # brows at rest
    np.testing.assert_allclose(rest.landmarks[[13, 14, 152]], face[[13, 14, 152]], atol=1e-5)  # lips closed
    assert rest.scores[NAMES.index("browInnerUp")] == 0.0 and rest.scores[NAMES.index("jawOpen")] == 0.0
    # A single neutral frame cannot do both: frame 0 has raised brows, frame 90 an open jaw.
    assert np.abs(frame_rest(lm, scores, NAMES, 0).landmarks[BROWS] - face[BROWS]).max() == pytest.approx(0.8)
    assert rest.single_frame is None and frame_rest(lm, scores, NAMES, 5).single_frame == 5


def test_regions_cover_the_face_and_the_eyes_stay_near_the_lids():
    regions = landmark_regions()
    assert regions.shape == (478,) and set(regions) == {0, 1, 2}
    assert regions[105] == REGIONS.index("brows") and regions[159] == REGIONS.index("eyes")
    assert regions[13] == REGIONS.index("mouth") and (regions[468:] == REGIONS.index("eyes")).all()
    assert regions[205] == REGIONS.index("mouth")  # the cheek moves with the mouth, not the lids


def test_geometry_is_in_interocular_distances():
    face = _face()
    g = rest_geometry(face[None] * 3.0)[0]  # scale-free
    iod = np.linalg.norm(face[IOD_PAIR[0]] - face[IOD_PAIR[1]])
    assert g[0] == pytest.approx(np.linalg.norm(face[13] - face[14]) / iod, rel=1e-5)


def test_never_relaxing_brows_are_warned_about():
    """Brows raised on every frame: one line naming the brows and the way out; none when
    they relax on some frames."""
    frames = np.arange(F)
    lm, scores = _clip(brows_raised=frames, mouth_open=frames[80:])
    lines = rest_warnings(_rest(lm, scores), NAMES)
    assert len(lines) == 1 and "brows never relax" in lines[0] and "browInnerUp 0.80" in lines[0]
    assert "--neutral-frame" in lines[0]
    lm, scores = _clip(brows_raised=frames[:80], mouth_open=frames[80:])
    assert rest_warnings(_rest(lm, scores), NAMES) == []


def test_the_track_stores_its_rest(tmp_path):
    """rest_fields -> Track -> save/load -> actor_rest gives the same rest back; a track
    without one rests on its neutral frame."""
    from capture2face.tracking.track import Track

    frames = np.arange(F)
    lm, scores = _clip(brows_raised=frames[:80], mouth_open=frames[80:])
    rest = _rest(lm, scores)
    track = Track(times=np.arange(F) / 30.0, landmarks_px=np.zeros((F, 478, 2), np.float32),
                  landmarks_depth=np.zeros((F, 478), np.float32), landmarks_head=lm.astype(np.float32),
                  presence=np.ones(F, bool), interpolated=np.zeros(F, bool), held=np.zeros(F, bool),
                  blendshapes=scores, blendshape_names=NAMES, head_pose=np.tile(np.eye(4, dtype=np.float32), (F, 1, 1)),
                  neutral_frame=3, width=64, height=64, fps=30.0)
    assert actor_rest(track).single_frame == 3
    stored = dataclasses.replace(track, **rest_fields(rest))
    stored.save(tmp_path / "t.npz")
    back = actor_rest(Track.load(tmp_path / "t.npz"))
    np.testing.assert_array_equal(back.landmarks, rest.landmarks)
    np.testing.assert_array_equal(back.face, rest.face)
    for key in (*REGIONS, FACE):
        np.testing.assert_array_equal(back.frames[key], rest.frames[key])

"""ARKit curves with ARKit meaning (capture2face.retarget.arkit) and their place in the
Animation and livelink.csv."""

from __future__ import annotations

import dataclasses
import zipfile

import numpy as np
import pytest
from conftest import shared_clip

from capture2face.retarget.animation import Animation
from capture2face.retarget.arkit import arkit_curves, calibrate_scores
from capture2face.topology import BLENDSHAPE_NAMES, IOD_PAIR, N_LANDMARKS
from capture2face.tracking import TrackOptions
from capture2face.tracking.filtering import one_euro
from capture2face.tracking.head_pose import canonical_mesh
from capture2face.tracking.track import Track

NAMES = list(BLENDSHAPE_NAMES)
F, NEUTRAL, FPS = 100, 3, 30.0


def _ramp(frames: np.ndarray, start: int, hold: int, length: int = 8) -> np.ndarray:
    """0 before ``start``, rising over ``length`` frames, 1 for ``hold`` frames, falling."""
    up = np.clip((frames - start) / length, 0, 1)
    down = np.clip((start + length + hold + length - frames) / length, 0, 1)
    return np.minimum(up, down)


def synthetic_track() -> tuple[Track, dict[str, np.ndarray]]:
    """A still canonical face that opens its jaw wide (0.4 inter-ocular distances of lip
    gap), closes the right eye and raises its brows (landmarks filtered as the tracker
    filters them), with MediaPipe-like scores: resting
    above 0 at the neutral and compressed (a full pose scores 0.6-0.8)."""
    verts = canonical_mesh().vertices.astype(np.float64)
    base = np.concatenate([verts, verts[:N_LANDMARKS - len(verts)]])
    iod = np.linalg.norm(base[IOD_PAIR[0]] - base[IOD_PAIR[1]])
    k = np.arange(F)
    jaw, blink, brow = _ramp(k, 30, 15), _ramp(k, 80, 4, 3), _ramp(k, 50, 10)
    lm = np.repeat(base[None], F, 0)
    lm[:, 14, 1] -= 0.4 * iod * jaw  # lower lip drops
    lm[:, 159, 1] -= 0.9 * (base[159, 1] - base[145, 1]) * blink  # right upper lid to 10% open
    lm[:, [105, 334], 1] += 0.1 * iod * brow[:, None]
    lm += np.random.default_rng(0).normal(0, 0.002, lm.shape)  # tracker jitter, cm
    lm = one_euro(lm, k / FPS, TrackOptions().landmark_filter(), speed_axis=-1)  # as the tracker filters
    scores = np.zeros((F, len(NAMES)))
    scores[:, NAMES.index("jawOpen")] = 0.2 + 0.55 * jaw
    scores[:, NAMES.index("eyeBlinkRight")] = 0.1 + 0.6 * blink
    scores[:, NAMES.index("browInnerUp")] = 0.05 + 0.3 * brow
    scores[:, NAMES.index("mouthSmileLeft")] = 0.3 + 0.7 * jaw  # a score with no geometry check
    track = Track(
        times=k / FPS, landmarks_px=np.zeros((F, 478, 2), np.float32), landmarks_depth=np.zeros((F, 478), np.float32),
        landmarks_head=lm.astype(np.float32), presence=np.ones(F, bool), interpolated=np.zeros(F, bool),
        held=np.zeros(F, bool), blendshapes=scores.astype(np.float32), blendshape_names=NAMES,
        head_pose=np.tile(np.eye(4, dtype=np.float32), (F, 1, 1)), neutral_frame=NEUTRAL, width=64, height=64,
        fps=FPS)
    return track, {"jawOpen": jaw, "eyeBlinkRight": blink, "browInnerUp": brow}


def test_calibration_puts_the_rest_at_zero_and_keeps_one_at_one():
    s = np.array([[0.3, 0.0], [0.65, 0.5], [1.0, 1.0], [0.1, 0.2]])
    np.testing.assert_allclose(calibrate_scores(s, s[0]), [[0, 0], [0.5, 0.5], [1, 1], [0, 0.2]])


def test_arkit_curves_have_arkit_meaning_on_a_synthetic_track():
    track, truth = synthetic_track()
    curves = arkit_curves(track)
    assert curves.shape == (F, 52) and curves.dtype == np.float32
    assert curves.min() >= 0 and curves.max() <= 1
    for name, pose in truth.items():
        c = curves[:, NAMES.index(name)]
        raw = track.blendshapes[:, NAMES.index(name)]
        assert c[NEUTRAL] < 0.02 < raw[NEUTRAL], name  # the clip's rest reads 0
        full = pose == 1
        assert c[full].min() > 0.9 > raw[full].max(), name  # the full pose reads ~1, the raw score less
        assert np.corrcoef(c, pose)[0, 1] > 0.97, name
    # Along the way too: 0.4 IOD of lip gap is ARKit's (ICT-FaceKit's) jawOpen 1, so half of it reads 0.5.
    jaw = curves[:, NAMES.index("jawOpen")]
    assert np.abs(jaw - truth["jawOpen"]).max() < 0.12
    # A curve without a geometry check: calibrated to the neutral, full range kept.
    smile = curves[:, NAMES.index("mouthSmileLeft")]
    assert smile[NEUTRAL] < 0.02 and smile[truth["jawOpen"] == 1].min() > 0.95
    untouched = [i for i, n in enumerate(NAMES) if n not in truth and n not in ("mouthSmileLeft", "_neutral",
                                                                                 "eyeBlinkLeft")]
    assert np.all(curves[:, untouched] == 0)
    assert curves[:, NAMES.index("eyeBlinkLeft")].max() < 0.05  # the still eye: jitter only


def test_lids_lowered_without_a_blink_score_are_not_a_blink():
    """Eyes looking down (or squinting) lower the lids while MediaPipe's blink score stays at
    rest: ARKit calls that eyeLookDown / eyeSquint, so eyeBlink stays near 0 there, while the
    blink itself (score and lids together) still reads ~1."""
    track, truth = synthetic_track()
    lm = np.array(track.landmarks_head)
    k = np.arange(F)
    look = _ramp(k, 55, 12)  # the right upper lid lowers a third of the way, no blink score
    lm[:, 159, 1] -= 0.33 * (lm[NEUTRAL, 159, 1] - lm[NEUTRAL, 145, 1]) * look
    curves = arkit_curves(dataclasses.replace(track, landmarks_head=lm.astype(np.float32)))
    blink = curves[:, NAMES.index("eyeBlinkRight")]
    assert blink[look == 1].max() < 0.05  # ungated: 0.42 (a third closed, full range 0.75)
    assert blink[truth["eyeBlinkRight"] == 1].min() > 0.9


def test_retarget_fills_the_arkit_curves_and_livelink_writes_them(tmp_path):
    import csv

    from capture2face.export.livelink import write_livelink_csv
    from capture2face.retarget import retarget
    from capture2face.rig.avatar import default_avatar

    track, _ = synthetic_track()
    anim = retarget(track, default_avatar())
    assert anim.arkit_names == NAMES and anim.arkit_weights.shape == (F, 52)
    np.testing.assert_array_equal(anim.arkit_weights, arkit_curves(track))
    path = tmp_path / "livelink.csv"
    write_livelink_csv(anim, track, path)
    lines = path.read_text().splitlines()
    col = lines[0].split(",").index("JawOpen")
    jaw = np.array([float(r[col]) for r in csv.reader(lines[1:])])
    np.testing.assert_allclose(jaw, anim.arkit_weights[:, NAMES.index("jawOpen")], atol=1e-6)
    anim.save(tmp_path / "animation.npz")
    back = Animation.load(tmp_path / "animation.npz")
    np.testing.assert_array_equal(back.arkit_weights, anim.arkit_weights)
    assert back.arkit_names == NAMES


def test_an_animation_file_without_arkit_curves_still_loads(tmp_path):
    track, _ = synthetic_track()
    n = 4
    anim = Animation(
        times=track.times[:n], fps=FPS, bone_names=["head"], bone_positions=np.zeros((n, 1, 3), np.float32),
        head_pose=track.head_pose[:n], blend_names=["jawOpen"], blend_weights=np.zeros((n, 1), np.float32),
        pose_names=["stretch"], influences=np.zeros((n, 1, 1), np.float32), rest_influence=np.ones((n, 1), np.float32),
        region_names=["forehead"], region_influence=np.zeros((n, 1, 1), np.float32), zone_names=["z"] * 8,
        zone_weights=np.zeros((n, 8), np.float32), mediapipe_blendshapes=track.blendshapes[:n],
        mediapipe_blendshape_names=NAMES, presence=np.ones(n, bool), character="default",
        arkit_names=NAMES, arkit_weights=np.zeros((n, 52), np.float32))
    anim.save(tmp_path / "new.npz")
    # An older file: the same archive without the two ARKit entries.
    with zipfile.ZipFile(tmp_path / "new.npz") as src, zipfile.ZipFile(tmp_path / "old.npz", "w") as dst:
        for item in src.infolist():
            if item.filename not in ("arkit_names.npy", "arkit_weights.npy"):
                dst.writestr(item, src.read(item.filename))
    old = Animation.load(tmp_path / "old.npz")
    assert old.arkit_weights is None and old.arkit_names == []
    np.testing.assert_array_equal(old.mediapipe_blendshapes, anim.mediapipe_blendshapes)


@pytest.mark.slow
@pytest.mark.shared_clips
def test_jaw_open_follows_the_mouth_on_a_real_clip():
    """d18 opens the jaw wide twice: JawOpen follows the mouth opening (r >= 0.9) and
    reaches >= 0.7, where the tracker's raw score (beside it) does worse on r."""
    from capture2face.measures import clip_fidelity
    from capture2face.pipeline import RunOptions, load_character, retarget_stage, track_stage

    track = track_stage(shared_clip("d18.mp4"), RunOptions(), progress=False)
    rig = load_character(None)
    anim = retarget_stage(track, rig)
    ours = clip_fidelity(track, anim, rig).figures()["arkit"]
    raw = clip_fidelity(track, dataclasses.replace(anim, arkit_weights=None), rig).figures()["arkit"]
    assert ours["jawOpen"]["r"] >= 0.9 and raw["jawOpen"]["r"] < ours["jawOpen"]["r"]  # raw: 0.86
    assert ours["jawOpen"]["max"] >= 0.7  # raw score: 0.93, but resting at 0.08
    for eye in ("eyeBlinkLeft", "eyeBlinkRight"):
        assert ours[eye]["r"] >= 0.9, eye  # raw: 0.91 / 0.86
    # She frowns through the clip and never raises her brows (0.02 IOD above rest at most):
    # browInnerUp is not judged and stays near 0 (it read 0.34 where the frown eased while
    # the curve's rest was the clip's lowest brows).
    assert not ours["browInnerUp"]["judged"] and ours["browInnerUp"]["max"] < 0.1

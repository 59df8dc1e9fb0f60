"""Expression fidelity on real clips (capture2face.measures, ``eval fidelity``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from capture2face.eval.fidelity import summary_line
from capture2face.measures import (
    MEASURES,
    ClipFidelity,
    character_measures,
    compare,
    direct_weights,
    faithful,
    lowpass,
    measures_from_points,
    rest_frames,
)
from capture2face.pipeline.report.figures import wrinkle_plots
from capture2face.pipeline.report.tables import fidelity_tables
from capture2face.rig.avatar import default_avatar
from tests.helpers import shared_clip


def _face(frames: int, gap: np.ndarray, eye_scale: np.ndarray) -> np.ndarray:
    """(F, 478, 3) a face with the measured landmarks placed by hand: IOD 6 cm, lips
    ``gap`` cm apart, eyes 1 cm open times ``eye_scale``."""
    pts = np.zeros((frames, 478, 3))
    pts[:, 33] = [-3.0, 0.0, 0.0]
    pts[:, 263] = [3.0, 0.0, 0.0]
    pts[:, 105] = [-2.0, 1.5, 0.0]
    pts[:, 334] = [2.0, 1.8, 0.0]
    pts[:, 13, 1] = -4.0 + gap / 2
    pts[:, 14, 1] = -4.0 - gap / 2
    pts[:, 61] = [-2.5, -4.0, 0.0]
    pts[:, 291] = [2.5, -4.0, 0.0]
    for upper, lower in ((159, 145), (386, 374)):
        pts[:, upper, 1] = 0.5 * eye_scale
        pts[:, lower, 1] = -0.5 * eye_scale
    return pts


def test_measures_are_in_inter_ocular_units_and_eyes_relative_to_neutral():
    gap = np.array([0.0, 0.6, 1.2])
    eyes = np.array([1.0, 0.5, 0.0])
    pts = _face(3, gap, eyes)
    m = measures_from_points(pts, pts[0])
    names = list(MEASURES)
    np.testing.assert_allclose(m[:, names.index("mouth_open")], gap / 6.0)
    np.testing.assert_allclose(m[:, names.index("mouth_width")], 5.0 / 6.0)
    np.testing.assert_allclose(m[:, names.index("brow_right")], np.hypot(1.0, 1.5) / 6.0)
    np.testing.assert_allclose(m[:, names.index("eye_left")], eyes)
    np.testing.assert_allclose(m[:, names.index("eye_right")], eyes)


def test_gain_and_correlation():
    t = np.linspace(0, 4 * np.pi, 200)
    src = np.sin(t)
    r, gain = compare(src, 0.5 * src + 3.0)
    assert r == pytest.approx(1.0) and gain == pytest.approx(0.5)
    r, _ = compare(src, -src)
    assert r == pytest.approx(-1.0)
    assert faithful(0.95, 1.0) and not faithful(0.95, 0.5) and not faithful(0.85, 1.0)


def test_lowpass_has_the_zero_phase_butterworth_response():
    """Sinusoids come out in phase, scaled by 1 / (1 + (f / 8 Hz)^4)."""
    fps = 30.0
    t = np.arange(600) / fps
    for hz in (1.0, 4.0, 12.0):
        wave = np.sin(2 * np.pi * hz * t)
        out = lowpass(np.stack([wave, 2 * wave], 1), fps)
        expected = 1.0 / (1.0 + (hz / 8.0) ** 4)
        np.testing.assert_allclose(out[60:-60, 0], expected * wave[60:-60], atol=0.01)
        np.testing.assert_allclose(out[:, 1], 2 * out[:, 0])


def test_character_at_rest_has_closed_lips_and_unit_eyes():
    rig = default_avatar()
    m = character_measures(rig, rig.bone_rest[None], np.zeros((1, rig.n_morphs)))[0]
    names = list(MEASURES)
    assert m[names.index("mouth_open")] < 0.01
    assert m[names.index("eye_left")] == pytest.approx(1.0)
    # jawOpen (the direct alternative's morph) opens the mouth and closes no eye.
    scores = np.zeros((1, 2))
    scores[0, 0] = 1.0
    w = direct_weights(rig, scores, ["jawOpen", "eyeBlinkLeft"])
    opened = character_measures(rig, rig.bone_rest[None], w)[0]
    assert opened[names.index("mouth_open")] > 0.1
    assert opened[names.index("eye_left")] == pytest.approx(1.0, abs=0.02)


def test_figures_judge_only_measures_that_move():
    n = 100
    t = np.linspace(0, 2 * np.pi, n)
    src = np.tile(np.sin(t)[:, None], (1, len(MEASURES))) * 0.1
    src[:, list(MEASURES).index("mouth_width")] *= 0.01  # range 0.002 IOD: not judged
    fid = ClipFidelity(name="x", times=t, source=src, character=src * 0.9, direct=src * 0.3,
                       arkit=np.sin(t)[:, None], arkit_names=["jawOpen"], arkit_source="animation")
    fig = fid.figures()
    assert not fig["measures"]["mouth_width"]["judged"]
    assert fig["measures"]["mouth_open"]["faithful"] and not fig["measures"]["mouth_open"]["direct_faithful"]
    assert fig["summary"] == {"judged": 3, "faithful": 3, "not_worse_than_direct": 3}
    assert fig["arkit"]["jawOpen"]["met"]


def test_direct_and_curves_drives_find_morphs_in_any_spelling():
    """A character whose morphs say ``eyeBlink_L`` (ICT, Face Cap) takes eyeBlinkLeft's
    score; an all-zero direct drive would make 'not worse than direct' mean nothing."""
    rig = default_avatar()
    renamed = rig.replace(morph_names=[n.replace("Left", "_L").replace("Right", "_R") for n in rig.morph_names])
    scores = np.array([[0.25, 0.75]])
    w = direct_weights(renamed, scores, ["jawOpen", "eyeBlinkLeft"])
    assert w[0, renamed.morph_names.index("eyeBlink_L")] == pytest.approx(0.75)
    assert w[0, renamed.morph_names.index("jawOpen")] == pytest.approx(0.25)
    assert np.count_nonzero(w) == 2


def test_figures_compare_with_the_curves_only_drive():
    n = 100
    t = np.linspace(0, 2 * np.pi, n)
    src = np.tile(np.sin(t)[:, None], (1, len(MEASURES))) * 0.1
    curves = src * 0.5
    curves[:, list(MEASURES).index("brow_left")] = src[:, 0] * 1.0  # the curves drive beats it here
    character = src * 0.7
    character[:, list(MEASURES).index("brow_left")] += np.cos(3 * t) * 0.05  # r ~0.8: behind on both
    fid = ClipFidelity(name="x", times=t, source=src, character=character, direct=src * 0.3,
                       arkit=np.sin(t)[:, None], arkit_names=["jawOpen"], arkit_source="animation", curves=curves)
    fig = fid.figures()
    assert fig["measures"]["brow_left"]["curves_faithful"] and not fig["measures"]["brow_left"]["faithful"]
    assert fig["measures"]["mouth_open"]["curves_gain"] == pytest.approx(0.5)
    assert fig["summary"]["not_worse_than_curves"] == fig["summary"]["judged"] - 1


SCORES = ["browInnerUp", "browDownLeft", "browDownRight", "jawOpen"]


def _brow_clip(lower: float, frown_score: float, compress: np.ndarray | None = None) -> ClipFidelity:
    """200 frames starting with the brows raised (0.08 IOD above a rest of 0.33): they rise
    on the positive half-waves, lower by ``lower`` on the negative ones (browDown
    ``frown_score``); the character's brows sit 0.08 low (its rest taken at frame 0, raised)
    and its lips follow the actor's; forehead stretch follows the raise, glabella compress
    the lowering (or ``compress``)."""
    t = np.linspace(0.5 * np.pi, 6.5 * np.pi, 200)
    up, down = np.maximum(np.sin(t), 0.0), np.maximum(-np.sin(t), 0.0)
    src = np.zeros((len(t), len(MEASURES)))
    names = list(MEASURES)
    brows = [names.index("brow_right"), names.index("brow_left")]
    src[:, brows] = (0.33 + 0.08 * up - lower * down)[:, None]
    src[:, names.index("mouth_open")] = 0.1 * down  # lips closed at rest
    character = src.copy()
    character[:, brows] += 0.30 - 0.41  # its rest brow (0.30) where the actor's was 0.41
    rest = np.zeros(len(MEASURES))
    rest[brows] = 0.30
    scores = np.stack([0.9 * up, frown_score * down, frown_score * down, 0.8 * down], 1)
    wrinkles = np.stack([0.7 * up, 0.5 * down if compress is None else compress], 1)
    return ClipFidelity(name="x", times=t, source=src, character=character, direct=src, arkit=scores,
                        arkit_names=SCORES, arkit_source="tracker", scores=scores, score_names=SCORES,
                        character_rest=rest, wrinkles=wrinkles)


def test_rest_frames_are_the_most_relaxed_not_the_first():
    fid = _brow_clip(0.03, 0.6)
    at = rest_frames(fid.scores, SCORES, "brows")
    assert len(at) == 20 and 0 not in at  # frame 0 holds the brows raised
    assert np.allclose(fid.brow()[at], 0.33, atol=0.015)  # frame 0: 0.41


def test_levels_see_the_character_rest_off_the_actors():
    """The character's brows 0.08 IOD below its rest where the actor's are at theirs: not
    met; the lips closed on both: met."""
    levels = _brow_clip(0.03, 0.6).figures()["levels"]
    assert levels["brows"]["offset"] == pytest.approx(-0.08, abs=0.005) and not levels["brows"]["met"]
    assert levels["mouth"]["offset"] == pytest.approx(0.0, abs=1e-6) and levels["mouth"]["met"]


def test_wrinkles_follow_the_brows_from_their_rest():
    w = _brow_clip(0.03, 0.6).figures()["wrinkles"]
    assert w["brow_rest"] == pytest.approx(0.33, abs=0.005)
    assert w["forehead_stretch"]["judged"] and w["forehead_stretch"]["r"] > 0.99 and w["forehead_stretch"]["met"]
    assert w["glabella_compress"]["judged"] and w["glabella_compress"]["r"] > 0.99
    assert w["glabella_compress"]["amount"] == pytest.approx(0.03, abs=0.002)
    assert not w["glabella_unfrowned"]["judged"]  # browDown reaches 0.6
    assert (w["judged"], w["met"]) == (2, 2)
    # Brows that never lower (browDown 0.02): a glabella that folds anyway fails, one that
    # stays flat passes; the lowering is too small to judge r.
    t = np.arange(200)
    folds = _brow_clip(0.0, 0.02, compress=0.4 + 0.05 * np.sin(t)).figures()["wrinkles"]
    assert not folds["glabella_compress"]["judged"]
    assert folds["glabella_unfrowned"]["judged"] and folds["glabella_unfrowned"]["p99"] == pytest.approx(0.45, abs=0.01)
    assert not folds["glabella_unfrowned"]["met"] and (folds["judged"], folds["met"]) == (2, 1)
    flat = _brow_clip(0.0, 0.02, compress=0.05 + 0.05 * np.sin(t)).figures()
    assert flat["wrinkles"]["glabella_unfrowned"]["met"]
    line = summary_line([_brow_clip(0.03, 0.6).figures(), flat])
    assert "levels: 2/4 brow and mouth rests" in line and "wrinkles: 4/4 checks met" in line
    assert "judged measures faithful" in line  # the old clauses stay
    page = fidelity_tables(flat)
    assert "glabella compress p99" in page and "forehead stretch r with brow raise" in page
    plots = wrinkle_plots(_brow_clip(0.03, 0.6), _brow_clip(0.03, 0.6).figures())
    assert len(plots) == 2 and "forehead stretch  r 1.00" in plots[0]


@pytest.mark.slow
@pytest.mark.shared_clips
def test_eval_fidelity_on_a_real_clip(tmp_path):
    """d18 (jaw open wide, pursed lips): the character opens its mouth as far as the actor,
    where the direct alternative (the avatar's jawOpen morph from the tracker's score)
    opens it about half as far."""
    clip = shared_clip("d18.mp4")
    out = tmp_path / "fidelity.json"
    env = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2")
    result = subprocess.run([sys.executable, "-m", "capture2face", "-q", "eval", "fidelity", str(clip),
                             "--json", str(out), "--plots", str(tmp_path)],
                            capture_output=True, text=True, timeout=900, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "judged measures faithful" in result.stdout
    figures = json.loads(out.read_text())["clips"][0]
    assert (tmp_path / "d18.fidelity.png").stat().st_size > 10_000
    mouth = figures["measures"]["mouth_open"]
    assert mouth["judged"] and mouth["r"] >= 0.9 and 0.8 <= mouth["gain"] <= 1.25
    assert mouth["direct_gain"] < 0.7  # the trivial alternative, for scale
    for eye in ("eye_left", "eye_right"):
        assert figures["measures"][eye]["r"] >= 0.9
    assert figures["arkit_source"] == "animation"
    assert figures["arkit"]["jawOpen"]["r"] >= 0.9 and figures["arkit"]["jawOpen"]["max"] >= 0.7
    # The actor frowns (browDown ~0.7): the glabella check for brows that never lower is not judged.
    assert "wrinkles:" in result.stdout and figures["levels"]["mouth"]["met"]
    assert figures["wrinkles"]["glabella_unfrowned"]["brow_down_max"] > 0.5
    assert not figures["wrinkles"]["glabella_unfrowned"]["judged"]

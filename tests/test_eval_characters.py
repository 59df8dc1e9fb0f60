"""``capture2face eval characters``: the gallery's sheets, figures and refusal rows."""

from __future__ import annotations

import json

import numpy as np
import pytest

from capture2face import cli
from capture2face.eval import characters
from capture2face.eval.contact_sheet import GAP, LABEL_BAND, Cell, draw_sheet, square_crop
from tests.helpers import REPO, shared_character

SAMPLE = REPO / "sample_videos" / "sample.mp4"


def test_square_crop_pads_outside_the_image():
    rgb = np.full((10, 10, 3), 200, np.uint8)
    crop = square_crop(rgb, (1, 1), 3)
    assert crop.shape == (6, 6, 3)
    assert (crop[:2, :2] == 0).all() and (crop[2:, 2:] == 200).all()


def test_sheet_size_and_labels():
    cells = [[Cell(np.full((50, 80, 3), 255, np.uint8), "a"), Cell(None, "b")], [Cell(None, "c")]]
    sheet = draw_sheet(cells, 64, ["title"])
    band = max(12, int(64 * LABEL_BAND))
    assert sheet.shape[1] == 2 * 64 + 3 * GAP
    assert sheet.shape[0] == GAP + max(14, int(6.4)) + 2 * (64 + band + GAP) + GAP


def test_peak_frame_skips_frames_without_a_face():
    class Anim:
        arkit_names = ["jawOpen", "browInnerUp"]
        arkit_weights = np.array([[0.9, 0], [0.5, 0], [0.7, 1]], np.float32)
        n_frames = 3

    class Tr:
        presence = np.array([False, True, True])
        neutral_frame = 1

    assert characters.peak_frame(Anim, Tr, ("jawOpen",)) == (2, pytest.approx(0.7))
    assert characters.peak_frame(Anim, Tr, None) == (1, 0.0)


def test_goals_met_follows_the_issues_thresholds():
    shading = {"mouth_open_r": 0.9, "mouth_open_gain": 0.7, "eyes_r": 0.8, "eyes_gain": 0.69,
               "brows_r": 0.74, "brows_gain": 1.0, "darkening_p95_mean": 0.03}
    met = characters.goals_met({"shading": shading, "fidelity": {"judged": 10, "faithful": 9}})
    assert met == {"mouth_open": True, "eyes": False, "brows": False, "darkening": True, "fidelity": True}
    assert "fidelity" not in characters.goals_met({"shading": shading, "fidelity": {"judged": 0, "faithful": 0}})


def test_darkening_cause_names_the_darkest_disc_its_frames_and_the_weights_then():
    """The disc with the highest p95, its darkest frames, and over them the mean weight of
    the most-weighted morphs beside the actor's curves (a solve that sets a morph the actor
    does not show stands out)."""
    from types import SimpleNamespace

    weights = np.zeros((6, 3), np.float32)
    weights[[2, 3], 0] = 0.8  # mouthSmileLeft in the dark frames
    weights[[2, 3], 2] = 1.0  # a shrug the actor does not show
    weights[0, 1] = 0.5  # outside the dark frames
    curves = np.zeros((6, 2), np.float32)
    curves[[2, 3], 1] = 0.6
    anim = SimpleNamespace(blend_names=["mouthSmileLeft", "jawOpen", "mouthShrugUpper"], blend_weights=weights,
                           arkit_names=["jawOpen", "mouthSmileLeft"], arkit_weights=curves)
    figures = {"darkening_p95": {"cheek_right": 0.01, "cheek_left": 0.05, "chin": 0.02},
               "darkening_frames": {"cheek_right": [[0, 0.02]], "cheek_left": [[3, 0.07], [2, 0.06]],
                                    "chin": [[5, 0.03]]}}
    got = characters.darkening_cause(anim, figures, top=2)
    assert got == {"disc": "cheek_left", "frames": [3, 2], "morphs": {"mouthShrugUpper": 1.0, "mouthSmileLeft": 0.8},
                   "curves": {"mouthSmileLeft": 0.6}}
    anim.arkit_weights = None  # a file written before the curves existed
    assert characters.darkening_cause(anim, figures)["curves"] == {}


def test_goals_leave_out_what_no_morph_moves_and_a_darkening_the_tracker_cannot_place():
    """A visemes-only head's brows and eyes (its posed ranges ~0) are not judged, its mouth
    and darkening are; a face judged on its posed landmarks (the tracker cannot read it) has
    no darkening goal: its discs would lie where the tracker guesses."""
    shading = {"mouth_open_r": 0.98, "mouth_open_gain": 0.9, "eyes_r": 0.15, "eyes_gain": 0.16,
               "brows_r": -0.4, "brows_gain": 0.2, "darkening_p95_mean": 0.02}
    posed = {"mouth_open_r": 0.99, "mouth_open_range_gain": 0.9, "brows_r": 0.3, "brows_range_gain": 0.7,
             "eyes_r": 0.9, "eyes_range_gain": 1.0, "mouth_open_range": 1.0, "brows_range": 0.0002,
             "eyes_range": 0.0007}
    fid = {"judged": 0, "faithful": 0}
    met = characters.goals_met({"shading": shading, "fidelity": fid, "posed": posed})
    assert met == {"mouth_open": True, "darkening": True}
    posed.update(eyes_range=0.6)
    met = characters.goals_met({"shading": shading, "fidelity": fid, "posed": posed, "follow_by": characters.POSED})
    assert met == {"mouth_open": True, "eyes": True}


def test_hair_hidden_leaves_out_the_overlays_only(avatar):
    """The check render's rig: every triangle of the overlays (hair and lash cards, glasses)
    gone, the rest kept as it was; a rig without overlays (the built-in avatar) has no check
    render of its own (None)."""
    from capture2face.eval.hair_hidden import hair_hidden

    assert hair_hidden(avatar) is None
    rig = avatar.replace(overlay_vertices=np.asarray(avatar.material) == 4)
    bare = hair_hidden(rig)
    over = rig.overlay_vertices[avatar.triangles[:, -1]]
    assert 0 < len(bare.triangles) < len(avatar.triangles)
    np.testing.assert_array_equal(bare.triangles, avatar.triangles[~over])
    assert hair_hidden(bare.replace(overlay_vertices=np.zeros(rig.n_vertices, bool))) is None


def _cell_is_blank(sheet: np.ndarray, row_top: int, col: int, cell: int) -> bool:
    x = GAP + col * (cell + GAP)
    return float(sheet[row_top:row_top + cell, x:x + cell].std()) < 2.0


@pytest.mark.slow
def test_gallery_on_the_sample_clip(tmp_path):
    """The built-in avatar and a shared character perform sample.mp4: a sheet each (three
    rows of six non-blank cells), figures in the JSON; a bad file gets its refusal row and
    the command still succeeds with the others done."""
    import cv2

    rpm = shared_character("rpm_male_xr_template_arkit52.glb")
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"not a glb")
    out, report = tmp_path / "gallery", tmp_path / "gallery.json"
    cell = 96
    assert cli.main(["eval", "characters", "default", str(bad), str(rpm), "--clip", str(SAMPLE), "-o", str(out),
                     "--size", "128", "--cell", str(cell), "--json", str(report), "-q"]) == 0
    rows = {r["name"]: r for r in json.loads(report.read_text())["characters"]}
    assert rows["broken"]["status"] == "refused" and "broken.glb" in rows["broken"]["message"]
    for name in ("default", rpm.stem):
        row = rows[name]
        assert row["status"] == "ok", row
        assert row["fidelity"]["judged"] > 0 and set(row["goals"]) >= {"mouth_open", "eyes", "brows", "darkening"}
        for key in ("mouth_open_r", "mouth_open_gain", "brows_r", "eyes_r", "darkening_p95_mean"):
            assert np.isfinite(row["shading"][key]), key
            assert np.isfinite(row["shading_hair_hidden"][key]), key
        assert (out / name / "avatar.mp4").is_file() and (out / name / "animation.glb").is_file()
        # the darkening read in the frames drawn with a flat base colour; avatar.mp4's beside it
        assert (out / name / "skin.mp4").is_file() and row["shading"]["darkening_read_in"] == "skin.mp4"
        assert np.isfinite(row["shading"]["darkening_p95_mean_avatar"])
        # where and when: each disc's darkest frames, and the morphs and curves behind the darkest disc
        assert set(row["shading"]["darkening_frames"]) == {"cheek_right", "cheek_left", "chin"}
        cause = row["darkening_cause"]
        assert cause["frames"] == [f for f, _ in row["shading"]["darkening_frames"][cause["disc"]]]
        sheet = cv2.imread(str(out / f"{name}.png"))
        band = max(12, int(cell * LABEL_BAND))
        assert sheet.shape[1] == 6 * cell + 7 * GAP
        top = sheet.shape[0] - GAP - 4 * (cell + band + GAP)  # the title's height
        for r in range(4):
            for c in range(6):
                assert not _cell_is_blank(sheet, top + GAP + r * (cell + band + GAP) + band, c, cell), (name, r, c)
    assert rows["default"]["shading"]["mouth_open_r"] > 0.8

"""Automatic landmarks on third-party heads (capture2face.character.landmarks): every tracker
landmark cast onto the skin's surface, the inner lips on their own lips, and the load-time
check that the fidelity pairs move with their morphs (capture2face.measures.landmark_faults)."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

import capture2face.character.landmarks as landmarks_module
from capture2face.character.landmarks import INNER_LIP_LOWER, INNER_LIP_UPPER, INNER_LIPS, with_surface_landmarks
from capture2face.character.load import load_character, warn_landmark_faults
from capture2face.eval.fidelity import summary_line, table
from capture2face.gltf import export_glb, import_glb
from capture2face.gltf.materials import overlay_vertices
from capture2face.measures import MEASURES, ClipFidelity, clip_fidelity, landmark_faults, rig_landmark_points
from capture2face.pipeline.report.tables import fidelity_tables
from capture2face.rig.arkit_names import arkit_morphs
from capture2face.rig.avatar import default_avatar
from capture2face.rig.face_rig import FaceRig, landmark_points
from tests.helpers import shared_character, synthetic_track


def _shared_character(name: str) -> FaceRig:
    return load_character(shared_character(name))


@pytest.fixture(scope="module", params=["ict-a.glb", "ict-b.glb"])
def head(request) -> FaceRig:
    return _shared_character(request.param)


def _morph(rig: FaceRig, arkit: str) -> np.ndarray:
    """(V, 3) float64 the rig's vertices under one ARKit morph at weight 1."""
    m = next(i for i, a in arkit_morphs(rig.morph_names).items() if a == arkit)
    return rig.vertices.astype(np.float64) + rig.morph_positions[m]


def test_every_fidelity_pair_moves_with_its_morph(head):
    assert head.landmark_faces is not None and head.landmark_bary is not None
    assert landmark_faults(head) == {}
    iod = head.interocular()
    rest = landmark_points(head, head.vertices.astype(np.float64))
    opened = landmark_points(head, _morph(head, "jawOpen"))
    gap = np.linalg.norm(rest[13] - rest[14]), np.linalg.norm(opened[13] - opened[14])
    assert gap[1] - gap[0] >= 0.25 * iod  # the check asks 0.15; ICT opens them ~0.39
    for blink, (a, b) in (("eyeBlinkLeft", (386, 374)), ("eyeBlinkRight", (159, 145))):
        closed = landmark_points(head, _morph(head, blink))
        assert np.linalg.norm(closed[a] - closed[b]) <= 0.45 * np.linalg.norm(rest[a] - rest[b])


def test_inner_lips_sit_on_their_own_lips(head):
    """Upper inner-lip landmarks on the upper lip, lower ones on the lower lip: jawOpen
    carries each lower one down by more than the upper one facing it (corners move with
    both), three times more in the middle; 13 and 14 share no vertex."""
    assert not set(head.landmark_faces[13]) & set(head.landmark_faces[14])
    rest = landmark_points(head, head.vertices.astype(np.float64))
    drop = rest[:, 1] - landmark_points(head, _morph(head, "jawOpen"))[:, 1]  # (L,) cm down
    upper, lower = drop[list(INNER_LIP_UPPER)], drop[list(INNER_LIP_LOWER)]  # facing pairs, right to left
    assert (lower - upper > 0.5).all()
    assert (lower[3:6] > 3.0 * upper[3:6]).all()
    assert rest[13, 1] > rest[14, 1]


def test_no_landmark_on_eyes_teeth_or_lashes(head):
    faces = head.landmark_faces
    assert (faces >= 0).all()
    assert (head.material[faces[:468]] == 0).all()  # the face's skin
    assert (head.material[faces[468:]] == 1).all()  # irises on the eyes
    assert head.overlay_vertices is not None and not head.overlay_vertices[faces].any()
    np.testing.assert_allclose(head.landmark_bary.sum(1), 1.0, atol=1e-5)
    assert (head.landmark_bary >= 0).all()
    # landmark_vertices: the nearest of the three.
    assert (head.landmark_vertices == faces[np.arange(len(faces)), np.argmax(head.landmark_bary, 1)]).all()


def _front_z(rig: FaceRig, vertices: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(K,) the largest z of the non-overlay surface (skin and eyes) above each point (K, 2)
    seen along z (-inf where none)."""
    keep = np.isin(rig.material, (0, 1, 4)) & ~rig.overlay_vertices
    tris = rig.triangles[keep[rig.triangles].all(1)]
    c = vertices[tris]  # (T, 3, 3)
    out = np.full(len(xy), -np.inf)
    for k, p in enumerate(xy):
        near = ((c[:, :, :2].min(1) <= p) & (c[:, :, :2].max(1) >= p)).all(1)
        a, b, cc = c[near, 0], c[near, 1], c[near, 2]
        v0, v1, v2 = b[:, :2] - a[:, :2], cc[:, :2] - a[:, :2], p - a[:, :2]
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        den = np.where(np.abs(den) < 1e-12, 1e-12, den)
        l1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
        l2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
        inside = (l1 >= 0) & (l2 >= 0) & (l1 + l2 <= 1)
        if inside.any():
            z = (1 - l1 - l2) * a[:, 2] + l1 * b[:, 2] + l2 * cc[:, 2]
            out[k] = z[inside].max()
    return out


def test_landmark_points_lie_on_the_front_surface(head):
    """No landmark behind the face (the eye socket behind an eyeball, the back of the head):
    each point is within 3 mm of the front-most surface over it (the inner lips with the
    mouth opened, where they were cast)."""
    rest = head.vertices.astype(np.float64)
    jaw = next(i for i, a in arkit_morphs(head.morph_names).items() if a == "jawOpen")
    opened = rest + 0.5 * head.morph_positions[jaw]
    lips = np.array(INNER_LIPS)
    others = np.setdiff1d(np.arange(468), lips)
    for verts, rows in ((rest, others), (opened, lips)):
        pts = landmark_points(head, verts, rows)
        front = _front_z(head, verts, pts[:, :2])
        assert np.isfinite(front).all()
        assert (pts[:, 2] >= front - 0.3).all(), rows[np.argmin(pts[:, 2] - front)]


def test_a_character_whose_jaw_does_not_open_its_lips_warns_and_leaves_the_measure_out(caplog):
    good = _shared_character("ict-a.glb")
    jaw = next(i for i, a in arkit_morphs(good.morph_names).items() if a == "jawOpen")
    mpos = good.morph_positions.copy()
    mpos[jaw] = 0.0
    bad = good.replace(morph_positions=mpos)
    with caplog.at_level(logging.WARNING, logger="capture2face"):
        faults = warn_landmark_faults(bad)
    assert list(faults) == ["mouth_open"]
    assert "13-14" in caplog.text and "jawOpen" in caplog.text
    # The fidelity figures (report.json, eval fidelity) leave it out instead of reporting 0.
    n = 50
    t = np.linspace(0, 4 * np.pi, n)
    src = np.stack([np.sin(t + k) for k in range(len(MEASURES))], 1)
    fid = ClipFidelity(name="c", times=t, source=src, character=src * 0.0, direct=src, arkit=np.zeros((n, 0)),
                       arkit_names=[], arkit_source="tracker", left_out=faults)
    fig = fid.figures()
    assert "mouth_open" not in fig["measures"] and "13-14" in fig["left_out"]["mouth_open"]
    assert fig["summary"]["judged"] == len(MEASURES) - 1
    assert "left out" in table([fig]) and f"/{len(MEASURES) - 1} judged" in summary_line([fig])
    assert "Left out: mouth_open" in fidelity_tables(fig)


def test_default_avatar_keeps_its_hand_set_landmarks():
    rig = default_avatar()
    assert rig.landmark_faces is None and rig.landmark_bary is None and rig.overlay_vertices is None
    assert landmark_faults(rig) == {}
    lv = rig.landmark_vertices
    have = lv >= 0
    pts = landmark_points(rig, rig.vertices)
    assert pts.dtype == rig.vertices.dtype and np.array_equal(pts[have], rig.vertices[lv[have]])
    assert rig.interocular() == float(np.linalg.norm(rig.vertices[lv[33]] - rig.vertices[lv[263]]))
    # Deformed: the vertex itself, bit for bit.
    rng = np.random.default_rng(0)
    weights = rng.uniform(0, 1, (3, rig.n_morphs))
    bones = rig.bone_rest[None] + rng.normal(0, 0.2, (3, rig.n_bones, 3))
    ids = np.array([13, 14, 33, 263, 468])
    got = rig_landmark_points(rig, bones, weights, ids)
    v = lv[ids]
    want = rig.vertices[v].astype(np.float64) + np.einsum("fm,mvc->fvc", weights, rig.morph_positions[:, v])
    want += np.einsum("vb,fbc->fvc", rig.dense_skin_weights()[v].astype(np.float64), bones - rig.bone_rest)
    assert np.array_equal(got, want)


def test_surface_landmarks_round_trip_through_the_rig_file(head, tmp_path):
    head.save(tmp_path / "rig.npz")
    back = FaceRig.load(tmp_path / "rig.npz")
    for name in ("landmark_faces", "landmark_bary", "overlay_vertices", "landmark_vertices"):
        a, b = getattr(head, name), getattr(back, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    np.testing.assert_array_equal(landmark_points(back, back.vertices), landmark_points(head, head.vertices))
    # And through the rig's own .glb (its capture2face extras).
    export_glb(head, tmp_path / "rig.glb")
    again = import_glb(tmp_path / "rig.glb")
    assert np.array_equal(again.landmark_faces, head.landmark_faces)
    assert np.array_equal(again.landmark_bary, head.landmark_bary)


def test_clip_fidelity_of_a_failing_character_leaves_the_measure_out():
    """The wiring of report.json's fidelity (clip_fidelity): the character's failing pair is
    checked where the figures are made."""
    good = _shared_character("ict-a.glb")
    mpos = good.morph_positions.copy()
    mpos[[i for i, a in arkit_morphs(good.morph_names).items() if a in ("eyeBlinkLeft", "jawOpen")]] = 0.0
    bad = good.replace(morph_positions=mpos)
    track, _ = synthetic_track()
    n = track.n_frames
    animation = SimpleNamespace(bone_positions=np.repeat(bad.bone_rest[None], n, 0),
                                blend_weights=np.zeros((n, bad.n_morphs), np.float32))
    fig = clip_fidelity(track, animation, bad, "x").figures()
    assert set(fig["left_out"]) == {"mouth_open", "eye_left"}
    assert set(fig["measures"]) == set(MEASURES) - {"mouth_open", "eye_left"}
    assert set(clip_fidelity(track, animation, good, "x").figures()["measures"]) == set(MEASURES)


def test_lash_cards_taken_for_skin_are_still_never_landed_on():
    """An importer may take an eyelash mesh for skin: its vertices, marked as an overlay (alpha
    MASK), still take no landmark, and the lids stay on the lids."""
    rig = import_glb(shared_character("ict-a.glb"))
    lashes = rig.overlay_vertices
    assert lashes is not None and lashes.sum() > 1000  # the EyeLashes mesh (MASK): 1368 vertices
    material = rig.material.copy()
    material[lashes] = 0
    cast = with_surface_landmarks(rig.replace(material=material))
    assert (cast.landmark_faces >= 0).all() and not lashes[cast.landmark_faces].any()
    assert landmark_faults(cast) == {}


def test_overlays_are_alpha_cards_and_named_meshes_never_the_skin():
    g = {"materials": [{"name": "Body", "alphaMode": "MASK"}, {"name": "Lashes", "alphaMode": "MASK"},
                       {"name": "Lens", "alphaMode": "BLEND"}, {"name": "M_Hair"}, {"name": "Teeth"}],
         "meshes": [{"name": "Head_Brows"}, {"name": "Glasses"}, {"name": "Mouth"}],
         "nodes": [{"mesh": 0}, {"mesh": 1}, {"mesh": 2}]}
    # Three meshes: the head (most triangles; its skin is MASKed and its name says brows),
    # glasses, a mouth with teeth and a hair card.
    mats = np.array([0, 0, 0, 1, 1, 2, 2, 4, 3, -1])
    parts = [{"offset": 0, "pos": np.zeros((5, 3)), "tri_count": 100},
             {"offset": 5, "pos": np.zeros((2, 3)), "tri_count": 4},
             {"offset": 7, "pos": np.zeros((3, 3)), "tri_count": 10}]
    spans = [(ni, slice(p["offset"], p["offset"] + len(p["pos"])), p["tri_count"]) for ni, p in enumerate(parts)]
    got = overlay_vertices(g, mats, 0, spans)
    assert got.tolist() == [False, False, False, True, True, True, True, False, True, False]


def test_lids_are_cast_again_with_eye_wide_only_where_the_rest_view_fails(monkeypatch):
    """With its left blink zeroed, a head's left lids fail the check at rest: they (and only
    they) are cast again in the eyeWide view; the inner lips once, in the jawOpen 0.5 view."""
    rig = import_glb(shared_character("ict-a.glb"))
    blink = next(i for i, a in arkit_morphs(rig.morph_names).items() if a == "eyeBlinkLeft")
    mpos = rig.morph_positions.copy()
    mpos[blink] = 0.0
    calls = []
    recast = landmarks_module._recast

    def spy(rig, out, view, fov, rows, what):
        calls.append((sorted(rows), what.split()[0]))
        recast(rig, out, view, fov, rows, what)

    monkeypatch.setattr(landmarks_module, "_recast", spy)
    cast = with_surface_landmarks(rig.replace(morph_positions=mpos))
    assert calls == [(sorted(INNER_LIPS), "mouth"), (sorted(landmarks_module.EYELIDS_LEFT), "eyes")]
    assert list(landmark_faults(cast)) == ["eye_left"]

"""A user's own ARKit character, driven with no mapping file: morph names in any spelling,
every mesh imported and moved, the head joint turned, textures packed, checked before
tracking. The characters are built in code from the default avatar
(capture2face.gltf.arkit_export); no third-party asset."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from capture2face.character.load import import_glb
from capture2face.errors import CaptureError
from capture2face.gltf.arkit_export import export_arkit_character, part_order
from capture2face.gltf.container import ARRAY_BUFFER, GlbBuilder, GlbReader
from capture2face.maths.stats import pearson
from capture2face.render import RenderOptions
from capture2face.rig.arkit_names import arkit_morphs, canonical_arkit, drive_mode
from capture2face.rig.avatar import default_avatar
from tests.helpers import FPS, NAMES, shared_character, synthetic_track, validate


@pytest.mark.parametrize("name, arkit", [
    ("eyeBlinkLeft", "eyeBlinkLeft"), ("EyeBlinkLeft", "eyeBlinkLeft"), ("eyeBlink_L", "eyeBlinkLeft"),
    ("eyeBlink.R", "eyeBlinkRight"), ("blendShape1.jawOpen", "jawOpen"), ("head:eyeBlink_R", "eyeBlinkRight"),
    ("blendShape1.eyeBlink.L", "eyeBlinkLeft"), ("Mouth_Smile_L", "mouthSmileLeft"), ("JAWOPEN", "jawOpen"),
    ("mouthLeft", "mouthLeft"), ("mouth_R", "mouthRight"), ("eyeLookIn_L", "eyeLookInLeft"),
    ("EyeBlink_Left", "eyeBlinkLeft"), ("tongueOut", "tongueOut"),
    ("Fcl_MTH_A", None), ("viseme_aa", None), ("jaw", None), ("eyeBlink", None), ("browInnerUp_L", None),
])
def test_arkit_names_in_every_spelling(name, arkit):
    assert canonical_arkit(name) == arkit


def _by_arkit(rig):
    return {a: m for m, a in arkit_morphs(rig.morph_names).items()}


@pytest.mark.parametrize("naming", ["_L", ".L", "blendShape1.", "Left_"])
def test_multi_mesh_arkit_character_imports_every_mesh_and_merges_morphs(tmp_path, avatar, naming):
    path = tmp_path / "head.glb"
    export_arkit_character(avatar, path, naming=naming)
    rig = import_glb(path)  # no mapping file
    # Head, eyes and mouth interior: a mesh each, all of them in, one after the other.
    order = part_order(avatar)
    assert rig.n_vertices == avatar.n_vertices
    np.testing.assert_allclose(rig.vertices, avatar.vertices[order], atol=1e-5)
    known = avatar.material[order] <= 3  # skin, eye, mouth, teeth: named by their meshes (the scalp imports as skin)
    np.testing.assert_array_equal(rig.material[known], avatar.material[order][known])
    assert drive_mode(rig) == "arkit"
    mine = _by_arkit(rig)
    assert set(mine) == set(avatar.morph_names)  # every ARKit morph, found under its spelling
    spans = 0
    for name, m in mine.items():
        # One morph per name over every mesh that carries it (eyes and teeth move with the face).
        np.testing.assert_allclose(rig.morph_positions[m], avatar.morph_positions[avatar.morph_index(name)][order],
                                   atol=1e-5)
        moved = np.abs(rig.morph_positions[m]).max(1) > 1e-4
        spans += len(np.unique(rig.material[moved])) >= 2
    assert spans >= 3  # some morphs (jawOpen: chin and teeth) span meshes


def test_quantized_character_reads_within_its_step(tmp_path, avatar):
    path = tmp_path / "q.glb"
    export_arkit_character(avatar, path, naming="_L", quantize=True)
    assert GlbReader._parse(path.read_bytes())[0]["extensionsRequired"] == ["KHR_mesh_quantization"]
    rig = import_glb(path)
    step_cm = 2e-3  # 0.02 mm
    order = part_order(avatar)
    assert np.abs(rig.vertices - avatar.vertices[order]).max() <= step_cm / 2 + 1e-5
    jaw = _by_arkit(rig)["jawOpen"]
    assert np.abs(rig.morph_positions[jaw] - avatar.morph_positions[avatar.morph_index("jawOpen")][order]).max() <= \
        step_cm / 2 + 1e-5


def test_arkit_character_is_driven_by_the_arkit_curves(tmp_path, avatar):
    # Imported without its landmarks cast (no automatic wrinkles): the curves drive it.
    from capture2face.retarget import retarget
    from capture2face.retarget.arkit import arkit_curves

    path = tmp_path / "head.glb"
    export_arkit_character(avatar, path, naming="_L")
    rig = import_glb(path)
    track, truth = synthetic_track()
    anim = retarget(track, rig)
    curves = arkit_curves(track)
    for name, m in _by_arkit(rig).items():
        expect = curves[:, NAMES.index(name)] if name in NAMES else 0.0
        np.testing.assert_allclose(anim.blend_weights[:, m], expect, atol=1e-6)
    # The geometry follows: the lower lip's vertex (largest jawOpen delta) moves with the
    # curve, and the curve with the synthetic jaw.
    jaw = _by_arkit(rig)["jawOpen"]
    v = int(np.argmax(np.linalg.norm(rig.morph_positions[jaw], axis=1)))
    from capture2face.rig.deform import deform

    pos, _ = deform(rig, anim.bone_positions, anim.blend_weights)
    drop = np.linalg.norm(pos[:, v] - rig.vertices[v], axis=1)
    assert np.corrcoef(drop, truth["jawOpen"])[0, 1] > 0.95
    assert drop.max() > 0.8 * np.linalg.norm(rig.morph_positions[jaw, v])  # a full opening reaches ~1
    np.testing.assert_array_equal(anim.bone_positions, np.repeat(rig.bone_rest[None], track.n_frames, 0))


def _with_landmarks(rig, avatar):
    """The imported avatar with the avatar's own landmark vertices and one automatic
    feature bone (as :mod:`capture2face.character.auto_wrinkles` gives an imported ARKit
    character, without its front view tracked): the Dutreve path of an ARKit character."""
    from capture2face.rig.feature_points import AUTO_PREFIX

    order = part_order(avatar)
    inv = np.empty(len(order), np.int64)
    inv[order] = np.arange(len(order))
    lv = np.where(avatar.landmark_vertices >= 0, inv[avatar.landmark_vertices.clip(0)], -1).astype(np.int32)
    rest = rig.vertices[lv[105]]
    return rig.replace(
        landmark_vertices=lv, bone_names=rig.bone_names + [AUTO_PREFIX + "brow"],
        bone_rest=np.concatenate([rig.bone_rest, rest[None]]).astype(np.float32),
        bone_parents=np.r_[rig.bone_parents, 0].astype(np.int32),
        bone_landmarks=np.r_[rig.bone_landmarks, 105].astype(np.int32),
        bone_groups=np.r_[rig.bone_groups, rig.bone_groups.max() + 1].astype(np.int32),
        pose_bones=np.concatenate([rig.pose_bones, np.repeat(rest[None, None], len(rig.pose_bones), 0)],
                                  1).astype(np.float32))


def _performed_track(rig, by: dict[str, int], truth: dict[str, np.ndarray], scores: dict[str, np.ndarray]):
    """A track whose landmarks are ``rig``'s own landmark points under the ``truth`` morph
    weights (F,) by ARKit name (an actor with the character's face: the weights to find),
    with MediaPipe-like ``scores`` (the others 0)."""
    from capture2face.rig.face_rig import landmark_points
    from capture2face.tracking.track import Track

    frames = len(next(iter(truth.values())))
    w = np.zeros((frames, rig.n_morphs))
    for name, curve in truth.items():
        w[:, by[name]] = curve
    verts = rig.vertices + np.einsum("fm,mvc->fvc", w, rig.morph_positions)
    lm = landmark_points(rig, verts).astype(np.float32)  # (F, 478, 3)
    s = np.zeros((frames, len(NAMES)), np.float32)
    for name, curve in scores.items():
        s[:, NAMES.index(name)] = curve
    return Track(times=np.arange(frames) / FPS, landmarks_px=np.zeros((frames, 478, 2), np.float32),
                 landmarks_depth=np.zeros((frames, 478), np.float32), landmarks_head=lm,
                 presence=np.ones(frames, bool), interpolated=np.zeros(frames, bool), held=np.zeros(frames, bool),
                 blendshapes=s, blendshape_names=NAMES, head_pose=np.tile(np.eye(4, dtype=np.float32), (frames, 1, 1)),
                 neutral_frame=0, width=64, height=64, fps=FPS)


def test_arkit_character_is_retargeted_from_the_feature_points(tmp_path, avatar):
    """Dutreve's retargeting onto an ARKit character: its morph weights are solved, bounded
    to [0, 1], from the feature points; the ARKit curves are the prior and drive what the
    points cannot see; Animation.arkit_weights keeps the curves."""
    from capture2face.retarget import RetargetOptions, retarget
    from capture2face.retarget.arkit import arkit_curves

    path = tmp_path / "head.glb"
    export_arkit_character(avatar, path, naming="_L")
    rig = _with_landmarks(import_glb(path), avatar)
    assert drive_mode(rig) == "arkit"
    by = _by_arkit(rig)
    k = np.arange(120)
    jaw, blink, brow, wide = (np.clip(1 - np.abs(k - c) / 12, 0, 1) for c in (25, 55, 80, 100))
    truth = {"jawOpen": 0.8 * jaw, "eyeBlinkRight": blink, "browInnerUp": 0.7 * brow, "noseSneerLeft": 0.6 * wide}
    puff = np.clip(np.sin(k / 20), 0, 1)
    scores = {"jawOpen": 0.1 + 0.35 * jaw,  # underrated and resting above 0, as MediaPipe's are
              "eyeBlinkRight": 0.1 + 0.6 * blink, "browInnerUp": 0.05 + 0.3 * brow,
              "mouthSmileLeft": 0.9 * jaw,  # a score the geometry does not show
              "cheekPuff": puff}  # a score the points cannot see
    track = _performed_track(rig, by, truth, scores)
    curves = arkit_curves(track)
    # A perfect actor with the character's own face: its depth is kept whole, and its
    # range is the character's (not a human's, which retarget.ranges maps onto the character's).
    anim = retarget(track, rig, RetargetOptions(depth_motion=1.0, arkit_own_range=False))
    only = retarget(track, rig, RetargetOptions(solve_blend_weights=False))  # the curves alone
    w = anim.blend_weights
    assert w.min() >= 0.0 and w.max() <= 1.0
    np.testing.assert_array_equal(anim.arkit_weights, curves)  # livelink.csv's ARKit meaning
    np.testing.assert_array_equal(anim.bone_positions, np.repeat(rig.bone_rest[None], len(k), 0))
    # The solved weights are the performed ones (the curves are not: the sneer has no
    # score at all, and the scores smile where the face does not).
    for name, curve in truth.items():
        assert np.abs(w[:, by[name]] - curve).max() < 0.2, name
    assert np.abs(w[:, by["jawOpen"]] - truth["jawOpen"]).max() < 0.05
    assert np.abs(only.blend_weights[:, by["noseSneerLeft"]] - truth["noseSneerLeft"]).max() > 0.5
    assert only.blend_weights[:, by["mouthSmileLeft"]].max() > 0.8 and w[:, by["mouthSmileLeft"]].max() < 0.2
    others = [m for a, m in by.items() if a not in truth and a not in scores]
    assert w[:, others].max() < 0.3 and w[:, others].mean() < 0.02
    # What the points cannot see takes its curve (cheekPuff: curve-only whatever it moves).
    np.testing.assert_allclose(w[:, by["cheekPuff"]], curves[:, NAMES.index("cheekPuff")], atol=1e-6)
    assert w[:, by["cheekPuff"]].max() > 0.9


@pytest.mark.parametrize("factor", [0.5, 2.0])
def test_arkit_character_performs_at_its_own_range(tmp_path, avatar, factor):
    """Issue 31: a character whose morphs move its landmarks ``factor`` times as
    far as the actor's face does raises its brows to the same weights (its own full range),
    not ``1 / factor`` of them."""
    from capture2face.retarget import RetargetOptions, retarget

    path = tmp_path / "head.glb"
    export_arkit_character(avatar, path, naming="_L")
    actor = _with_landmarks(import_glb(path), avatar)
    by = _by_arkit(actor)
    k = np.arange(120)
    brow, jaw = (np.clip(1 - np.abs(k - c) / 15, 0, 1) for c in (35, 85))
    truth = {"browInnerUp": brow, "browOuterUpLeft": brow, "browOuterUpRight": brow, "jawOpen": 0.9 * jaw}
    track = _performed_track(actor, by, truth, truth)
    rig = actor.replace(morph_positions=actor.morph_positions * np.float32(factor))  # every morph's size
    w = {name: retarget(track, r, RetargetOptions(depth_motion=1.0)).blend_weights for name, r in
         (("own", actor), ("scaled", rig))}
    # The brows (their pairs carry the fit); the jaw is held back by the lips' contour points,
    # which still follow the network (2x: 0.44 where its own face reaches 0.70).
    for name in ("browInnerUp", "browOuterUpLeft", "browOuterUpRight"):
        own, other = w["own"][:, by[name]], w["scaled"][:, by[name]]
        if factor > 1 and name != "browInnerUp":
            # 2x: this avatar's brows then rise 1.9 times a human's, its inner brow 2.9 times
            # as far as its mid brow against a human's: a brow of another shape, whose mid
            # brow follows the actor's at up to 1.15 of it (retarget.ranges.BROW_SHAPE_RATIO):
            # the outer raises in step with the own head's, short of its full range, not half.
            assert 0.6 * own.max() < other.max() < own.max() and pearson(own, other) > 0.95, (name, other.max())
            continue
        # 0.5x: what the character can do, at its full range; 2x: the same weights, not half.
        expected = np.minimum(own, 1.0)
        assert np.abs(other - expected).max() < 0.2, (name, other.max(), own.max())
    assert w["scaled"][:, by["browInnerUp"]].max() > 0.8
    # The raise is not cancelled by its antagonist: the actor never frowns (the solve set
    # browDown against the raise before co-activation was penalised).
    for name in ("browDownLeft", "browDownRight"):
        assert w["scaled"][:, by[name]].max() < 0.1, (name, w["scaled"][:, by[name]].max())


@pytest.mark.parametrize("name, other_shape", [("rpm_female_arkit_visemes.glb", True), ("ict-a.glb", False)])
def test_brows_of_another_shape_follow_the_actor_at_their_mid_pair(name, other_shape):
    """Issue 31: a Ready Player Me's browInnerUp raises its inner brow 2.7 times a human's,
    its outer raise its mid brow about as a human's: each brow pair scaled by its own morph,
    the three targets disagreed and the mid brow (what the measures read) followed at r
    0.82-0.89. There the inner and outer pairs weigh less and the mid pair rises to the head's
    full raise, up to 1.15 of the actor's; an ICT head's brows keep their ranges."""
    from capture2face.character.load import load_character
    from capture2face.retarget.arkit_solve import morph_solve
    from capture2face.retarget.driver import _skin_landmarks
    from capture2face.retarget.ranges import BROW_RATIO_MAX, BROW_SIDE_WEIGHT, range_targets

    rig = load_character(shared_character(name))
    landmarks = _skin_landmarks(rig)
    solve = morph_solve(rig, landmarks, 0.02, 0.1)
    ranged = range_targets(solve, landmarks, solve.model.rest[:len(landmarks)])
    sides, mids = [5, 6, 8, 9], [4, 7]  # positions of EXPRESSION_PAIRS 11, 12, 14, 15 and 10, 13
    if other_shape:
        assert np.allclose(ranged.weights[sides], BROW_SIDE_WEIGHT) and np.all(ranged.weights[mids] == 1.0)
        assert np.allclose(ranged.gain[mids, 0], BROW_RATIO_MAX)
    else:
        assert np.all(ranged.weights == 1.0) and np.all(np.abs(ranged.gain[:, 0] - 1.0) < 0.05)


def test_lids_do_not_cancel_where_eye_wide_opens_both(tmp_path, avatar):
    """Issue 31: on a head whose ``eyeWide`` opens both lids (a Ready Player Me head's: the
    lower as far as its ``eyeSquint`` raises it), an actor raising the upper lid alone is
    not made of both morphs cancelling on the lower lid (both at 1.00 before, where the
    actor never squints)."""
    from capture2face.retarget import RetargetOptions, retarget
    from capture2face.retarget.arkit_solve import morph_solve
    from capture2face.retarget.driver import _skin_landmarks

    path = tmp_path / "head.glb"
    export_arkit_character(avatar, path, naming="_L")
    actor = _with_landmarks(import_glb(path), avatar)
    by = _by_arkit(actor)
    lift = np.clip(1 - np.abs(np.arange(120) - 60) / 20, 0, 1)
    track = _performed_track(actor, by, {"eyeWideLeft": lift, "eyeWideRight": lift}, {})
    pos = actor.morph_positions.copy()
    for side in ("Left", "Right"):
        pos[by[f"eyeWide{side}"]] -= pos[by[f"eyeSquint{side}"]]
    rig = actor.replace(morph_positions=pos)

    def lid_pairs(r):
        solve = morph_solve(r, _skin_landmarks(r), 0.02)
        names = {k + solve.model.n_free_vars: canonical_arkit(r.morph_names[m])
                 for k, m in enumerate(solve.model.morphs)}
        return {(names[a], names[b]) for a, b in solve.antagonists if names[a].startswith("eyeWide")}

    assert lid_pairs(rig) == {("eyeWideLeft", "eyeSquintLeft"), ("eyeWideRight", "eyeSquintRight")}
    w = retarget(track, rig, RetargetOptions(depth_motion=1.0)).blend_weights
    for side in ("Left", "Right"):
        squint, wide = w[:, by[f"eyeSquint{side}"]], w[:, by[f"eyeWide{side}"]]
        assert squint.max() < 0.05 and wide.max() > 0.3, (side, squint.max(), wide.max())  # 0.09 without the pair


def test_lid_pairs_are_antagonists_only_where_they_move_against_each_other():
    """An ICT head's eyeWide moves the upper lid only: no pair there (its solve unchanged)."""
    from capture2face.retarget.arkit_solve import LID_ANTAGONISTS, LID_OPPOSITION, opposed_pairs

    def opposed_lid_pairs(named, deltas):
        return opposed_pairs(named, deltas, LID_ANTAGONISTS, LID_OPPOSITION)

    upper, lower = np.zeros((2, 3)), np.zeros((2, 3))
    upper[0, 1], lower[1, 1] = 1.0, 1.0  # (points, xyz): the upper lid's point, the lower's
    named = {0: "eyeWideLeft", 1: "eyeSquintLeft"}
    only_upper = np.stack([upper + 0.05 * -lower, lower])  # a wide whose lower lid barely moves
    both = np.stack([upper - lower, lower])  # Ready Player Me's: both lids open
    assert opposed_lid_pairs(named, only_upper) == ()
    assert opposed_lid_pairs(named, both) == (("eyeWideLeft", "eyeSquintLeft"),)


@pytest.mark.parametrize(("name", "opposed"), [
    ("rpm_female_arkit_visemes.glb", True), ("rpm_male_xr_template_arkit52.glb", True),
    ("ict-a.glb", False), ("ict-b.glb", False),
])
def test_funnel_and_stretch_are_antagonists_where_they_move_the_lips_apart(name, opposed):
    """Issue 31: a Ready Player Me head's mouthFunnel draws its corners in as far as its
    mouthStretch pulls them out (cosine over the lips -0.60 to -0.62): the solve made d18's
    grimace of both (0.52 and 0.95 where the curves show 0.01 and 0.02-0.05). There the two
    are an antagonist pair; an ICT head's (-0.49 / -0.50) keep its solve."""
    from capture2face.character.load import load_character
    from capture2face.retarget.arkit_solve import morph_solve
    from capture2face.retarget.driver import _skin_landmarks

    rig = load_character(shared_character(name))
    solve = morph_solve(rig, _skin_landmarks(rig), 0.02, 0.1)
    names = {k + solve.model.n_free_vars: canonical_arkit(rig.morph_names[m]) for k, m in enumerate(solve.model.morphs)}
    pairs = {(names[a], names[b]) for a, b in solve.antagonists if names[a] == "mouthFunnel"}
    assert pairs == ({("mouthFunnel", "mouthStretchLeft"), ("mouthFunnel", "mouthStretchRight")} if opposed else set())


def test_opposed_pairs_judge_each_pair_by_its_cosine():
    from capture2face.retarget.arkit_solve import opposed_pairs

    corner = np.zeros((2, 3))
    corner[0, 0] = 1.0
    named = {0: "mouthFunnel", 1: "mouthStretchLeft", 2: "mouthStretchRight"}
    deltas = np.stack([-corner + 0.5 * np.roll(corner, 1, 0), corner, corner + np.roll(corner, 1, 0)])
    pairs = (("mouthFunnel", "mouthStretchLeft"), ("mouthFunnel", "mouthStretchRight"),
             ("mouthFunnel", "mouthSmileLeft"))
    # cosines -0.89 and -0.32; mouthSmileLeft is not on the head
    assert opposed_pairs(named, deltas, pairs, -0.55) == (("mouthFunnel", "mouthStretchLeft"),)
    assert opposed_pairs(named, deltas, pairs, -0.3) == pairs[:2]


def test_head_joint_turns_the_head_and_not_the_body(tmp_path, avatar):
    from capture2face.camera import face_centre_and_height, rotation_matrix
    from capture2face.render.skinning import Deformer

    path = tmp_path / "body.glb"
    export_arkit_character(avatar, path, naming="_L", skeleton=True, body=True)
    rig = import_glb(path)
    assert rig.bone_names[0] == "head" and {"Hips", "Neck"} <= set(rig.bone_names)
    face = rig.material != 0
    face[: avatar.n_vertices] = True
    np.testing.assert_allclose(rig.head_weights[face], 1.0)
    np.testing.assert_allclose(rig.head_weights[~face], 0.0)  # the body hangs on the hips
    rot = rotation_matrix(30.0, 0.0, 0.0)
    d = Deformer(rig)
    zero = np.zeros(rig.n_morphs)
    turned = d.positions(rig.bone_rest, zero, head_rotation=rot)
    pivot = rig.bone_rest[0].astype(np.float64)
    np.testing.assert_allclose(turned[face], (rig.vertices[face] - pivot) @ rot.T + pivot, atol=1e-4)
    np.testing.assert_allclose(turned[~face], rig.vertices[~face], atol=1e-6)
    # The camera frames the face (what the morphs move), not the body under it.
    centre, height = face_centre_and_height(rig)
    a_centre, a_height = face_centre_and_height(avatar)
    assert abs(centre[1] - a_centre[1]) < 0.1 * a_height and height < 1.2 * a_height


def test_atlas_keeps_each_mesh_texture(tmp_path, avatar):
    path = tmp_path / "body.glb"
    export_arkit_character(avatar, path, naming="_L", body=True)
    rig = import_glb(path)
    body = np.arange(avatar.n_vertices, rig.n_vertices)
    h, w = rig.albedo.shape[:2]
    assert w == 2 * h  # two tiles: the face's texture and the outfit's

    def sample(uv):
        return rig.albedo[np.clip((uv[:, 1] * h).astype(int), 0, h - 1), np.clip((uv[:, 0] * w).astype(int), 0, w - 1)]

    centre = rig.uvs[body].mean(0, keepdims=True)  # the middle of the outfit's tile
    assert np.abs(sample(centre).astype(int) - [50, 80, 160]).max() < 25
    # Face UVs land in the face tile and read the avatar's albedo there.
    face = np.flatnonzero(avatar.material == 0)[::50]
    mine = np.argsort(part_order(avatar))[face]  # the same vertices in the character
    ah, aw = avatar.albedo.shape[:2]
    expect = avatar.albedo[np.clip((avatar.uvs[face, 1] * ah).astype(int), 0, ah - 1),
                           np.clip((avatar.uvs[face, 0] * aw).astype(int), 0, aw - 1)]
    assert np.median(np.abs(sample(rig.uvs[mine]).astype(int) - expect).max(1)) < 12


def test_mapping_json_maps_other_names(tmp_path, avatar):
    path = tmp_path / "vroid.glb"
    export_arkit_character(avatar, path, naming="_L")
    gltf, binary = GlbReader._parse(path.read_bytes())
    for mesh in gltf["meshes"]:  # a VRoid-like set: Fcl_ names
        names = mesh.get("extras", {}).get("targetNames", [])
        mesh.get("extras", {})["targetNames"] = [
            t.replace("jawOpen", "Fcl_MTH_A").replace("eyeBlink_L", "Fcl_EYE_Close_L") for t in names]
    out = tmp_path / "fcl.glb"
    _write_glb(out, gltf, binary)
    assert "jawOpen" not in _by_arkit(import_glb(out))
    (tmp_path / "fcl.json").write_text(
        json.dumps({"morphs": {"Fcl_MTH_A": "jawOpen", "Fcl_EYE_Close_L": "eyeBlink_L"}}))
    rig = import_glb(out)
    mine = _by_arkit(rig)
    assert "jawOpen" in mine and "eyeBlinkLeft" in mine
    np.testing.assert_allclose(rig.morph_positions[mine["jawOpen"]],
                               avatar.morph_positions[avatar.morph_index("jawOpen")][part_order(avatar)], atol=1e-5)
    (tmp_path / "fcl.json").write_text(json.dumps({"morphs": {"Fcl_MTH_A": "mouthWide"}}))
    with pytest.raises(CaptureError, match="must be an ARKit blendshape name, not 'mouthWide'"):
        import_glb(out)


def _write_glb(path, gltf: dict, binary: bytes) -> None:
    bld = GlbBuilder()
    bld.gltf, bld.bin = gltf, bytearray(binary)
    path.write_bytes(bld.to_bytes())


def _static_morph_glb(path, names, extensions=()):
    """A triangle with morph targets of the given names, no skin."""
    bld = GlbBuilder()
    pos = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], np.float32)
    targets = [{"POSITION": bld.accessor(np.full((3, 3), 0.01, np.float32), ARRAY_BUFFER, minmax=True)}
               for _ in names]
    bld.add("meshes", {"primitives": [{"attributes": {"POSITION": bld.accessor(pos, ARRAY_BUFFER, minmax=True)},
                                       "targets": targets}], "extras": {"targetNames": list(names)}})
    bld.add("nodes", {"mesh": 0})
    bld.gltf["scenes"] = [{"nodes": [0]}]
    if extensions:
        bld.gltf["extensionsUsed"] = bld.gltf["extensionsRequired"] = list(extensions)
    path.write_bytes(bld.to_bytes())
    return path


def test_undrivable_character_says_what_is_missing(tmp_path):
    from capture2face.pipeline.preflight import check_character

    bad = _static_morph_glb(tmp_path / "shapes.glb", ["Key 1", "Key 2"])
    with pytest.raises(CaptureError, match="no ARKit names and no face bones") as err:
        check_character(bad)
    assert "\n" not in str(err.value)
    ok = _static_morph_glb(tmp_path / "jaw.glb", ["Jaw_Open"])
    assert drive_mode(check_character(ok)) == "arkit"
    visemes = _static_morph_glb(tmp_path / "visemes.glb", ["viseme_aa", "viseme_O"])  # other conventions drive
    assert drive_mode(check_character(visemes)) == "arkit"


@pytest.mark.parametrize("ext", ["EXT_mesh_gpu_instancing", "KHR_gaussian_splatting"])
def test_unsupported_required_extension_is_named(tmp_path, ext):
    path = _static_morph_glb(tmp_path / "x.glb", ["jawOpen"], extensions=[ext])
    with pytest.raises(CaptureError, match=ext) as err:
        import_glb(path)
    assert "\n" not in str(err.value)


def test_meshopt_without_its_package_is_named(tmp_path, monkeypatch):
    path = _static_morph_glb(tmp_path / "x.glb", ["jawOpen"], extensions=["EXT_meshopt_compression"])
    monkeypatch.setitem(sys.modules, "meshoptimizer", None)  # as where the sdist could not build
    with pytest.raises(CaptureError, match="EXT_meshopt_compression.*pip install meshoptimizer") as err:
        import_glb(path)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kind", ["undrivable", "instancing"])
def test_cli_refuses_a_bad_character_before_tracking(tmp_path, sample_clip, kind):
    path = _static_morph_glb(tmp_path / "c.glb", ["Key 1"] if kind == "undrivable" else ["jawOpen"],
                             extensions=["EXT_mesh_gpu_instancing"] if kind == "instancing" else ())
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "capture2face", "run", str(sample_clip), "-o", str(tmp_path / "out"),
                           "--character", str(path)], capture_output=True, text=True, timeout=120)
    took = time.perf_counter() - t0
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and ("no ARKit names" in lines[0] if kind == "undrivable"
                                else "EXT_mesh_gpu_instancing" in lines[0])
    assert not (tmp_path / "out" / sample_clip.stem).exists()  # nothing tracked, nothing written
    print(f"refused in {took:.1f} s")


# ---- animation.glb for the user's character ---------------------------------------------------
def _accessor(gltf, binary: bytes, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc.type]
    return np.frombuffer(binary, np.float32, acc.count * width, view.byteOffset + (acc.byteOffset or 0)).reshape(
        acc.count, width)


@pytest.mark.parametrize("skeleton", [True, False])
def test_animation_glb_of_the_users_character(tmp_path, avatar, skeleton):
    import pygltflib

    from capture2face.camera import face_centre_and_height, rotation_ypr
    from capture2face.gltf.animation_export import head_rotations
    from capture2face.gltf.character import export_character_animation
    from capture2face.retarget import retarget

    src = tmp_path / "char.glb"
    export_arkit_character(avatar, src, naming="_L", skeleton=skeleton, body=skeleton)
    rig = import_glb(src)
    track, _ = synthetic_track()
    angles = np.zeros((track.n_frames, 3))
    angles[:, 0] = 25 * np.sin(np.linspace(0, 3, track.n_frames))  # yaw
    track.head_pose[:, :3, :3] = rotation_ypr(angles)
    anim = retarget(track, rig)
    out = tmp_path / "animation.glb"
    export_character_animation(src, rig, anim, out)
    before, after = pygltflib.GLTF2().load(str(src)), pygltflib.GLTF2().load(str(out))
    binary = after.binary_blob()
    assert len(after.meshes) == len(before.meshes) and len(after.materials) == len(before.materials)
    (a,) = after.animations
    assert a.extras["fps"] == pytest.approx(track.fps) and a.extras["frames"] == track.n_frames
    channels = {(c.target.node, c.target.path): a.samplers[c.sampler].output for c in a.channels}
    times = _accessor(after, binary, a.samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(track.n_frames) / track.fps, atol=1e-5)
    morph_nodes = [i for i, n in enumerate(after.nodes) if n.mesh is not None and after.meshes[n.mesh].extras]
    assert len(morph_nodes) >= 2  # head and teeth carry morphs
    by = _by_arkit(rig)
    for i in morph_nodes:
        names = after.meshes[after.nodes[i].mesh].extras["targetNames"]
        w = _accessor(after, binary, channels[(i, "weights")]).reshape(track.n_frames, len(names))
        for t, name in enumerate(names):
            np.testing.assert_allclose(w[:, t], anim.blend_weights[:, by[canonical_arkit(name)]], atol=1e-6)
    expect = head_rotations(track.head_pose)
    if skeleton:  # the head joint turns (its rest rotation is the identity here)
        head = next(j for j in after.skins[0].joints if after.nodes[j].name == "Head")
        q = _accessor(after, binary, channels[(head, "rotation")])
        assert not any(path == "rotation" for (node, path) in channels if node != head)  # the body stays
    else:  # a root over the scene turns the character about its face centre
        root = next(i for i, n in enumerate(after.nodes) if n.name == "capture2face_root")
        assert after.scenes[0].nodes == [root]
        q = _accessor(after, binary, channels[(root, "rotation")])
        shift = _accessor(after, binary, channels[(root, "translation")])
        centre = face_centre_and_height(rig)[0] / 100.0
        turned = np.einsum("fij,j->fi", track.head_pose[:, :3, :3].astype(np.float64), centre) + shift
        np.testing.assert_allclose(turned, np.broadcast_to(centre, turned.shape), atol=1e-5)
    np.testing.assert_allclose(np.abs(np.einsum("fi,fi->f", q, expect)), 1.0, atol=1e-5)
    report = validate(out)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"][:5]


def test_run_drives_an_arkit_character_with_no_mapping_file(tmp_path, avatar, sample_clip):
    import av
    import pygltflib

    from capture2face.pipeline import RunOptions, run

    char = tmp_path / "char.glb"
    export_arkit_character(avatar, char, naming=".L", skeleton=True, body=True)
    report = run(sample_clip, tmp_path / "out", RunOptions(character=char, render=RenderOptions(size=128)),
                 progress=False)
    folder = tmp_path / "out" / sample_clip.stem
    with av.open(str(folder / "avatar.mp4")) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == report["frames"] == 90
    # The face, not a blank frame: the middle of every frame differs from the background.
    bg = frames[0][1, 1].astype(int)
    middle = np.stack([f[40:88, 40:88] for f in frames]).astype(int)
    assert np.abs(middle - bg).max(-1).mean(axis=(1, 2)).min() > 30
    glb = pygltflib.GLTF2().load(str(folder / "animation.glb"))
    assert [m.name for m in glb.meshes] == ["Head", "Eyes", "Mouth", "Teeth", "Scalp", "Body"]  # the user's own file
    assert glb.animations[0].extras["frames"] == 90


# ---- compressed and WebP files ------------------------------------------------------------------
def _meshopt_compressed(src, dst) -> int:
    """``src`` with every vertex-attribute and index view stored as an
    EXT_meshopt_compression stream (what gltfpack -c writes); returns how many views."""
    meshoptimizer = pytest.importorskip("meshoptimizer")
    gltf, binary = GlbReader._parse(src.read_bytes())
    sizes = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
    comp = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
    kind = {}
    for acc in gltf["accessors"]:
        v = acc.get("bufferView")
        if v is not None and acc["type"] in sizes:
            kind[v] = sizes[acc["type"]] * comp[acc["componentType"]]
    out, fallback, n = bytearray(), 0, 0
    for i, view in enumerate(gltf["bufferViews"]):
        data = binary[view.get("byteOffset", 0): view.get("byteOffset", 0) + view["byteLength"]]
        target, stride = view.get("target"), view.get("byteStride") or kind.get(i)
        out.extend(b"\0" * (-len(out) % 4))
        if target == 34962 and stride and stride % 4 == 0:
            count = len(data) // stride
            enc = meshoptimizer.encode_vertex_buffer(np.frombuffer(data, np.uint8).reshape(count, stride),
                                                     count, stride)
            ext = {"buffer": 0, "byteOffset": len(out), "byteLength": len(enc), "byteStride": stride, "count": count,
                   "mode": "ATTRIBUTES"}
        elif target == 34963 and stride == 4:
            idx = np.frombuffer(data, np.uint32)
            enc = meshoptimizer.encode_index_buffer(idx, len(idx), int(idx.max()) + 1)
            ext = {"buffer": 0, "byteOffset": len(out), "byteLength": len(enc), "byteStride": 4, "count": len(idx),
                   "mode": "TRIANGLES"}
        else:
            view["byteOffset"] = len(out)
            out.extend(data)
            continue
        out.extend(enc)
        view.update(buffer=1, byteOffset=fallback, extensions={"EXT_meshopt_compression": ext})
        if target == 34962:
            view["byteStride"] = stride
        fallback += len(data) + (-len(data) % 4)
        n += 1
    gltf["buffers"] = [{"byteLength": len(out)},
                       {"byteLength": fallback, "extensions": {"EXT_meshopt_compression": {"fallback": True}}}]
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["EXT_meshopt_compression"]
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    out.extend(b"\0" * (-len(out) % 4))
    total = 12 + 8 + len(text) + 8 + len(out)
    dst.write_bytes(b"glTF" + (2).to_bytes(4, "little") + total.to_bytes(4, "little") + len(text).to_bytes(4, "little")
                    + b"JSON" + text + len(out).to_bytes(4, "little") + b"BIN\0" + bytes(out))
    return n


def test_meshopt_compressed_character_reads_like_the_plain_one(tmp_path, avatar):
    plain = tmp_path / "plain.glb"
    export_arkit_character(avatar, plain, naming="_L")
    packed = tmp_path / "packed.glb"
    assert _meshopt_compressed(plain, packed) >= 10
    assert packed.stat().st_size < plain.stat().st_size
    a, b = import_glb(plain), import_glb(packed)
    np.testing.assert_array_equal(b.vertices, a.vertices)
    # The index codec keeps each triangle and its winding but may start it at another corner.
    def rolled(t):
        k = np.argmin(t, axis=1)
        return np.stack([t[np.arange(len(t)), (k + i) % 3] for i in range(3)], 1)

    np.testing.assert_array_equal(rolled(b.triangles), rolled(a.triangles))
    np.testing.assert_array_equal(b.morph_positions, a.morph_positions)
    assert b.morph_names == a.morph_names


def test_webp_textures_are_read(tmp_path, avatar):
    import cv2

    plain = tmp_path / "plain.glb"
    export_arkit_character(avatar, plain, naming="_L")
    gltf, binary = GlbReader._parse(plain.read_bytes())
    ok, webp = cv2.imencode(".webp", cv2.cvtColor(avatar.albedo, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_WEBP_QUALITY, 101])
    assert ok
    bld = GlbBuilder()
    bld.gltf, bld.bin = gltf, bytearray(binary)
    image = bld.add("images", {"bufferView": bld.buffer_view(webp.tobytes()), "mimeType": "image/webp"})
    tex = gltf["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["index"]
    gltf["textures"][tex]["extensions"] = {"EXT_texture_webp": {"source": image}}
    gltf["textures"][tex]["source"] = gltf["textures"][1]["source"]  # the fallback: another image
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["EXT_texture_webp"]
    out = tmp_path / "webp.glb"
    out.write_bytes(bld.to_bytes())
    rig = import_glb(out)
    np.testing.assert_array_equal(rig.albedo, avatar.albedo)  # lossless WebP: the same pixels


# ---- automatic wrinkle influences ----------------------------------------------------------------
def test_automatic_wrinkle_influences_follow_the_morphs(tmp_path, avatar):
    from capture2face.pipeline import load_character
    from capture2face.rig import influences as inf
    from capture2face.rig.arkit_names import is_automatic
    from capture2face.rig.feature_points import feature_positions

    path = tmp_path / "char.glb"
    export_arkit_character(avatar, path, naming="_L", skeleton=True, body=True)
    rig = load_character(path)  # no mapping file: the front view is tracked
    assert is_automatic(rig) and drive_mode(rig) == "arkit"
    # The tracked landmarks land where the avatar's are (the same face): MediaPipe's own
    # error on a rendered face is ~0.15 cm.
    ok = (rig.landmark_vertices[:468] >= 0) & (avatar.landmark_vertices[:468] >= 0)
    err = np.linalg.norm(rig.vertices[rig.landmark_vertices[:468][ok]]
                         - avatar.vertices[avatar.landmark_vertices[:468][ok]], axis=1)
    assert ok.sum() == 468 and np.median(err) < 0.4
    # A frown, then raised brows, then a smile: the glabella's compress influence follows
    # the frown, the forehead's stretch influence the raised brows.
    by = _by_arkit(rig)
    k = np.arange(120)
    frown, raised, smile = (np.clip(1 - np.abs(k - c) / 15, 0, 1) for c in (25, 60, 95))
    w = np.zeros((len(k), rig.n_morphs), np.float32)
    for name in ("browDownLeft", "browDownRight"):
        w[:, by[name]] = frown
    for name in ("browInnerUp", "browOuterUpLeft", "browOuterUpRight"):
        w[:, by[name]] = raised
    w[:, by["mouthSmileLeft"]] = w[:, by["mouthSmileRight"]] = smile
    regions = inf.region_influence(inf.rig_influences(feature_positions(rig, w), rig), rig)
    glabella = regions[:, rig.region_names.index("glabella"), rig.pose_names.index("compress")]
    forehead = regions[:, rig.region_names.index("forehead"), rig.pose_names.index("stretch")]
    assert np.corrcoef(glabella, frown)[0, 1] > 0.9 and glabella.max() > 0.3
    assert np.corrcoef(forehead, raised)[0, 1] > 0.9 and forehead.max() > 0.3
    assert glabella[raised > 0.5].max() < 0.05 and forehead[frown > 0.5].max() < 0.05
    # The wrinkle maps and zone masks baked into its UV space (the face's atlas tile, the
    # left half) are the avatar's (the same face, the same UVs), where the avatar has any,
    # up to the landmark fit's error (~0.2 cm: a few texels' shift).
    h, w = rig.albedo.shape[:2]
    assert w == 2 * h == 2 * avatar.wrinkle_maps.shape[1]
    for name in ("stretch", "compress"):
        baked = rig.wrinkle_maps[rig.wrinkle_map_names.index(name), :, : w // 2].astype(int)
        theirs = avatar.wrinkle_maps[avatar.wrinkle_map_names.index(name)].astype(int)
        lines = (theirs != [128, 128, 255]).any(-1)
        assert np.corrcoef((baked - 128)[lines].ravel(), (theirs - 128)[lines].ravel())[0, 1] > 0.9, name
        diff = min((np.abs(np.roll(baked, (dy, dx), (0, 1)) - theirs).max(-1)[lines] for dy in range(-8, 9, 2)
                    for dx in range(-8, 9, 2)), key=np.median)
        assert np.median(diff) <= 4 and (diff > 24).mean() < 0.2, name
    assert (rig.wrinkle_maps[:, :, w // 2:] == [128, 128, 255]).all()  # the body's tile stays flat
    zones = rig.zone_masks[:, : w // 2].astype(int)
    assert np.abs(zones - avatar.zone_masks.astype(int)).max(-1).mean() < 3
    # The feature points never move the mesh: the Animation keeps them at rest.
    from capture2face.retarget import retarget

    track, _ = synthetic_track()
    anim = retarget(track, rig)
    np.testing.assert_array_equal(anim.bone_positions, np.repeat(rig.bone_rest[None], track.n_frames, 0))
    assert anim.influences.max() > 0.3  # the synthetic track raises the brows


def test_node_transforms_place_every_mesh_in_the_scene(tmp_path, avatar):
    """An FBX-style file: the meshes under an 'Armature' node turned 90 degrees about x and
    scaled by 0.01 (centimetre data): vertices, normals and morph deltas come out turned
    and scaled as the scene shows them."""
    plain = tmp_path / "plain.glb"
    export_arkit_character(avatar, plain, naming="_L")
    gltf, binary = GlbReader._parse(plain.read_bytes())
    s = np.sqrt(0.5)
    gltf["nodes"].append({"name": "Armature", "rotation": [s, 0.0, 0.0, s], "scale": [0.01] * 3,
                          "children": list(gltf["scenes"][0]["nodes"])})
    gltf["scenes"][0]["nodes"] = [len(gltf["nodes"]) - 1]
    turned = tmp_path / "turned.glb"
    _write_glb(turned, gltf, binary)
    a, b = import_glb(plain), import_glb(turned)
    rot = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +90 degrees about x
    np.testing.assert_allclose(b.vertices, a.vertices @ rot.T * 0.01, atol=1e-5)
    np.testing.assert_allclose(b.normals, a.normals @ rot.T, atol=1e-5)
    np.testing.assert_allclose(b.morph_positions, a.morph_positions @ rot.T * 0.01, atol=1e-6)


def test_a_scanned_head_is_framed_on_its_face_not_its_bust():
    """ICT's morphs also move the neck: framing the vertices the morphs move showed head,
    neck and shoulders (32 cm tall); once its landmarks are found, the face is framed as
    the default avatar's is."""
    from capture2face.camera import face_centre_and_height
    from capture2face.pipeline import load_character

    rig = load_character(shared_character("ict-a.glb"))
    centre, height = face_centre_and_height(rig)
    _, default_height = face_centre_and_height(default_avatar())
    assert 0.8 * default_height < height < 1.2 * default_height, (height, default_height)
    nose = rig.vertices[rig.landmark_vertices[1]]
    assert abs(centre[1] - nose[1]) < 0.25 * height  # centred on the face, not below it


@pytest.mark.parametrize("name", ["ict-a.glb", "ict-b.glb"])
def test_a_scanned_head_folds_only_where_its_pose_moves_it(name):
    """ICT's "compress" pose (browDown + eyeSquint + noseSneer) moves its chin's feature
    points by 0.06-0.12 cm: given a part in that pose, pressed lips drew the compress map's
    folds on the chin at rest (d18's compare.mp4 on ict-a). A feature the pose barely moves takes
    no part; the brows still fold with a frown."""
    from capture2face.character.auto_wrinkles import MIN_POSE_SHARE
    from capture2face.pipeline import load_character
    from capture2face.rig import influences as inf
    from capture2face.rig.feature_points import feature_positions

    rig = load_character(shared_character(name))
    travel = np.linalg.norm(rig.pose_bones - rig.bone_rest[None], axis=-1)  # (P, B)
    share = travel / travel.max(1, keepdims=True)
    assert (share[travel > 1e-6] >= MIN_POSE_SHARE).all()
    by = _by_arkit(rig)
    k = np.arange(60)
    press, frown = (np.clip(1 - np.abs(k - c) / 10, 0, 1) for c in (15, 45))
    w = np.zeros((len(k), rig.n_morphs), np.float32)
    for morph in ("mouthPressLeft", "mouthPressRight", "mouthShrugLower"):
        w[:, by[morph]] = 0.6 * press
    for morph in ("browDownLeft", "browDownRight"):
        w[:, by[morph]] = frown
    regions = inf.region_influence(inf.rig_influences(feature_positions(rig, w), rig), rig)
    compress = rig.pose_names.index("compress")
    chin = regions[:, rig.region_names.index("chin"), compress]
    glabella = regions[:, rig.region_names.index("glabella"), compress]
    assert chin.max() < 0.05  # with the chin in the pose: 0.6 and more
    assert glabella[frown > 0.9].min() > 0.3 and glabella[press > 0.9].max() < 0.05



def _lid_model(shut: list[float]):
    """A :class:`MorphSolve` of the twelve lid landmarks alone: its six pairs 1 cm apart at
    rest, two blinks closing them by ``shut`` (right eye's three columns, then the left's)."""
    from capture2face.retarget.arkit_solve import EXPRESSION_PAIRS, MorphSolve
    from capture2face.retarget.solve import LinearRigModel

    landmarks = np.asarray(EXPRESSION_PAIRS[:6]).ravel()
    n = len(landmarks)
    rest = np.zeros((n + 6, 3))
    rest[n:, 0] = 1.0
    matrix = np.zeros((3 * (n + 6), 2))
    matrix[3 * (n + np.arange(6)), np.repeat([0, 1], 3)] = -np.asarray(shut)
    model = LinearRigModel(rest=rest, matrix=matrix, free_bones=np.zeros(0, np.int64), morphs=np.array([0, 1]))
    solve = MorphSolve(model=model, fixed=np.zeros(0, np.int64), fixed_deltas=np.zeros((0, n, 3)),
                       pairs=np.arange(n).reshape(6, 2))
    return solve, landmarks, {0: "eyeBlinkRight", 1: "eyeBlinkLeft"}


def test_side_lid_columns_close_on_the_head_s_own_lid_shape():
    """Issue 31: where a head's blink closes its lids' side columns by another share of their
    opening than the middle one (the XR head's 0.99 and 0.88 against 0.80), each side
    column's closing target is the actor's times that ratio, up to shut; its opening is
    left as mapped. A human's even blink (the ICT heads': sides within 0.04 of the middle)
    and a blink that leaves a column open (under 0.75 shut) keep the mapped targets."""
    from capture2face.retarget.arkit_solve import lid_ratios

    solve, landmarks, named = _lid_model([0.80, 0.99, 0.88, 0.86, 0.84, 0.86])
    ratios = lid_ratios(solve, named, landmarks)
    np.testing.assert_allclose(ratios, [1.0, 0.99 / 0.80, 0.88 / 0.80, 1.0, 1.0, 1.0])
    solve.lid_ratios = ratios
    n = len(landmarks)
    pts = np.repeat(solve.model.rest[None], 3, 0)
    pts[:, n:, 0] = np.array([0.5, 1.2, 0.1])[:, None]  # half closed, opened, nearly shut
    out = solve.lid_targets(pts)
    np.testing.assert_allclose(out[0, n:, 0], 1.0 - 0.5 * ratios)
    np.testing.assert_array_equal(out[1], pts[1])
    np.testing.assert_allclose(out[2, n:, 0], np.maximum(1.0 - 0.9 * ratios, 0.0))
    for even in ([0.87, 0.84, 0.87, 0.86, 0.84, 0.86], [0.65, 0.91, 0.59, 0.65, 0.91, 0.61]):
        solve, landmarks, named = _lid_model(even)
        assert lid_ratios(solve, named, landmarks) is None
        assert solve.lid_targets(pts) is pts


@pytest.mark.slow
def test_the_xr_head_closes_its_middle_lid_with_the_actor():
    """Issue 31: an ICT head's half blink (its columns close together) performed onto Ready
    Player Me's XR head, whose blink closes the lid's inner column 0.99 of the way and its
    middle 0.80: its middle lid (the eye's measured opening) closes with the actor's, by
    its blink, not its squint. Before, the solve held the blink back to fit the side
    columns (0.50 where the actor's is 0.6, its squint at 0.15) and the middle closed 0.85 of
    the actor's way."""
    from capture2face.character.load import load_character
    from capture2face.retarget import retarget
    from capture2face.rig.face_rig import landmark_points

    actor = load_character(shared_character("ict-a.glb"))
    head = load_character(shared_character("rpm_male_xr_template_arkit52.glb"))
    blink = 0.6 * np.clip(1 - np.abs(np.arange(90) - 45) / 15, 0, 1)
    curves = {"eyeBlinkLeft": blink, "eyeBlinkRight": blink}
    track = _performed_track(actor, _by_arkit(actor), curves, curves)
    w = retarget(track, head).blend_weights
    by = _by_arkit(head)
    for side, pair in (("Right", [159, 145]), ("Left", [386, 374])):
        rest, shut = (landmark_points(head, head.vertices + np.einsum("m,mvc->vc", w[f].astype(np.float64),
                                                                       head.morph_positions), pair) for f in (0, 45))
        actor = np.linalg.norm(track.landmarks_head[[0, 45], pair[0]] - track.landmarks_head[[0, 45], pair[1]], axis=-1)
        closing = 1 - np.linalg.norm(shut[0] - shut[1]) / np.linalg.norm(rest[0] - rest[1])
        actor_closing = 1 - actor[1] / actor[0]
        assert closing > 0.9 * actor_closing, (side, closing, actor_closing)  # 0.855 before
        assert w[45, by[f"eyeSquint{side}"]] < 0.1, side  # 0.15 before

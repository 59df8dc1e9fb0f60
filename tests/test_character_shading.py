"""Third-party characters render right: morph normals combined as glTF defines them (the
file's own, or derived where it has none), alpha modes, unreadable textures.

The shared ICT-FaceKit head (``../shared/characters/ict-a.glb``: NORMAL deltas on Head,
none on GumsTongue, a MASK eyelash mesh) is the test character; variants of it are
written with pygltflib into tmp_path. Skipped where the shared folder is absent.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from capture2face import default_avatar
from capture2face.camera import framing_pose
from capture2face.gltf import export_glb, import_glb
from capture2face.gltf.welding import weld_ids as _weld
from capture2face.render import FrameState, Renderer, RenderOptions
from capture2face.render.skinning import Deformer
from capture2face.rig.deform import deform
from capture2face.rig.face_rig import FaceRig
from capture2face.rig.mesh_ops import vertex_normals
from tests.helpers import shared_character

# An open "O" with raised brows and half-closed lids: the frame that turned Ready Player
# Me's lower face dark red-brown when its derived morph normals were wrong.
COMBO = {"jawOpen": 0.87, "browInnerUp": 1.0, "browOuterUpLeft": 0.8, "browOuterUpRight": 0.8,
         "eyeBlinkLeft": 0.6, "eyeBlinkRight": 0.6}


def _variant(tmp_path_factory, name: str, change) -> Path:
    gltf = pygltflib.GLTF2().load(str(shared_character("ict-a.glb")))
    change(gltf)
    path = tmp_path_factory.mktemp("ict") / name
    gltf.save(str(path))
    return path


def _strip_morph_normals(gltf) -> None:
    for mesh in gltf.meshes:
        for prim in mesh.primitives:
            for target in prim.targets or []:
                target.pop("NORMAL", None)


@pytest.fixture(scope="module")
def ict(tmp_path_factory) -> FaceRig:
    return import_glb(shared_character("ict-a.glb"))


@pytest.fixture(scope="module")
def ict_derived(tmp_path_factory) -> FaceRig:
    """ict-a without any NORMAL deltas: every morph's normals derived at import."""
    return import_glb(_variant(tmp_path_factory, "no_morph_normals.glb", _strip_morph_normals))


def _weights(rig: FaceRig) -> np.ndarray:
    w = np.zeros(rig.n_morphs, np.float32)
    for name, value in COMBO.items():
        w[rig.morph_index(name)] = value
    return w


def _welded_normals(rig: FaceRig, positions: np.ndarray) -> np.ndarray:
    ids = _weld(rig.vertices)
    first = np.unique(ids, return_index=True)[1]
    return vertex_normals(np.asarray(positions, np.float64)[first], ids[rig.triangles])[ids]


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip((a * b).sum(1), -1.0, 1.0)))


@pytest.mark.parametrize("which", ["own", "derived"])
def test_combined_morph_normals_follow_the_deformed_mesh(which, ict, ict_derived):
    """Several morphs at once: the renderer's normals (rest + sum w * delta, normalised)
    stay within a few degrees of the deformed mesh's own recomputed normals, wherever the
    file's rest normals are the recomputed ones (elsewhere the file's normals are its own
    choice). With deltas taken against the file's normals (the old derivation) the p99
    was 42 degrees (the gums and tongue have no NORMAL deltas in the file), 92 with every
    morph's derived."""
    rig = ict if which == "own" else ict_derived
    w = _weights(rig)
    deformer = Deformer(rig)
    positions, normals = deformer(rig.bone_rest, w)
    _, ref_normals = deform(rig, rig.bone_rest, w)
    assert np.abs(ref_normals - normals).max() < 1e-4  # the reference deformation agrees
    agree = _angles(rig.normals, _welded_normals(rig, rig.vertices)) < 3.0
    assert agree.mean() > 0.98
    off = _angles(normals, _welded_normals(rig, positions))[agree]
    assert np.percentile(off, 99) < 6.0
    # The eye corners half way through a blink fold over (the deformed mesh's own normals
    # there are no reference): four vertices.
    assert (off > 10.0).sum() < 40 and (off > 45.0).sum() <= 4


def test_derived_normal_deltas_are_zero_where_a_morph_moves_nothing(ict_derived):
    """A derived normal delta is exactly 0 at every vertex whose triangles a morph leaves
    alone (the old derivation, against the file's normals, changed every normal that
    differs from the recomputed one: 0.3-1.9 around a mouth that brows do not move);
    eyeWideLeft, which moves the left upper lid, changes no normal below the eyes."""
    rig = ict_derived
    ids = _weld(rig.vertices.astype(np.float64) / 100.0)  # as the import welds: in the file's metres
    tris = ids[rig.triangles]
    for k in range(rig.n_morphs):
        moved = np.zeros(ids.max() + 1, bool)
        moved[ids[np.abs(rig.morph_positions[k]).max(1) > 0]] = True
        touched = np.zeros_like(moved)
        touched[tris[moved[tris].any(1)]] = True
        assert not rig.morph_normals[k][~touched[ids]].any(), rig.morph_names[k]
    k = rig.morph_index("eyeWideLeft")
    changed = np.abs(rig.morph_normals[k]).max(1) > 0
    assert 500 < changed.sum() < 3000 and rig.vertices[changed, 1].min() > 0.0
    assert (np.linalg.norm(rig.morph_normals, axis=2) <= 2.0 + 1e-5).all()


def test_file_normal_deltas_transform_like_normals_in_the_node_frame(tmp_path_factory, ict):
    """A scaled, turned Head node: rest + delta, normalised, is the file's normal plus its
    delta carried by the node's inverse transpose (glTF), at every Head vertex."""
    scale, angle = np.array([1.4, 0.7, 1.1]), np.radians(20.0)
    quat = [0.0, float(np.sin(angle / 2)), 0.0, float(np.cos(angle / 2))]

    def turn(gltf):
        gltf.nodes[0].scale = scale.tolist()
        gltf.nodes[0].rotation = quat

    path = _variant(tmp_path_factory, "scaled_head.glb", turn)
    rig = import_glb(path)
    gltf = pygltflib.GLTF2().load(str(path))
    head = np.arange(gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION].count)  # node 0's vertices
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    normal_rows = np.linalg.inv(rot * scale)  # rows: n^T inv(L)
    k = rig.morph_index("jawOpen")
    assert np.abs(ict.morph_normals[k][head]).max() > 0.1
    expected = (ict.normals[head] + 0.8 * ict.morph_normals[k][head]) @ normal_rows
    got = rig.normals[head] + 0.8 * rig.morph_normals[k][head]
    assert _angles(got, expected).max() < 0.05
    expected_rest = ict.normals[head] @ normal_rows
    assert _angles(rig.normals[head], expected_rest).max() < 0.05


def _render(rig: FaceRig, weights=None, size: int = 256, eyes: bool = False, pose=None) -> np.ndarray:
    """A frame of ``rig`` at 3/4 view (``eyes``: the eyes close up, a 9 degree field)."""
    fov = 9.0 if eyes else 30.0
    if pose is None:
        pose = framing_pose(rig, yaw=15.0, pitch=-5.0, fov_y_degrees=30.0)
    if eyes:  # the eyes' midpoint on the optical axis
        cam = pose[:3, :3] @ rig.vertices[rig.material == 1].mean(0) + pose[:3, 3]
        pose = pose.copy()
        pose[:2, 3] -= cam[:2]
    w = np.zeros(rig.n_morphs, np.float32) if weights is None else weights
    with Renderer(rig, RenderOptions(size=size, samples=1, wrinkles="off", fov_y_degrees=fov)) as r:
        return r.render(FrameState(rig.bone_rest, w, pose))


def test_combined_morphs_shade_as_the_deformed_mesh(ict_derived):
    """The frame drawn with the derived morph normals against the same frame drawn from
    the deformed mesh itself with its recomputed normals (where the file's rest normals
    are the recomputed ones): the same brightness to a few levels but at a few pixels."""
    rig = ict_derived
    w = _weights(rig)
    positions, normals = Deformer(rig)(rig.bone_rest, w)
    recomputed = _welded_normals(rig, positions).astype(np.float32)
    agree = _angles(rig.normals, _welded_normals(rig, rig.vertices)) < 3.0
    baked = rig.replace(vertices=positions, normals=np.where(agree[:, None], recomputed, normals),
                        morph_positions=np.zeros_like(rig.morph_positions),
                        morph_normals=np.zeros_like(rig.morph_normals))
    pose = framing_pose(rig, yaw=15.0, pitch=-5.0, fov_y_degrees=30.0)
    drawn, truth = _render(rig, w, pose=pose), _render(baked, np.zeros(rig.n_morphs, np.float32), pose=pose)
    luma_drawn, luma_truth = (im.astype(np.float64) @ [0.299, 0.587, 0.114] for im in (drawn, truth))
    face = luma_truth > 60  # the lit head, not the background
    diff = np.abs(luma_drawn - luma_truth)[face]
    assert face.sum() > 5000
    # Deltas against the file's normals (the old derivation): p99.9 17 levels, 48 pixels
    # off by more than 10; derived against the recomputed rest normals: 8.6 and 8.
    assert np.percentile(diff, 99.9) < 12.0 and (diff > 10).sum() < 25 and diff.mean() < 0.4


# d12's smile frame (22) on Ready Player Me as the solve mixes it: smile, squint and wide
# eyes, shrug: the cheeks creased dark (skin darkening p95 7.6 % on the right cheek).
RPM_SMILE = {"mouthShrugUpper": 0.98, "eyeWideRight": 0.72, "mouthSmileRight": 0.68, "eyeSquintRight": 0.64,
             "cheekSquintRight": 0.61, "mouthLowerDownRight": 0.59, "eyeWideLeft": 0.59, "browInnerUp": 0.55,
             "mouthSmileLeft": 0.53, "eyeSquintLeft": 0.48}


def test_a_user_heads_normals_turn_as_its_deformed_shape_under_combined_morphs():
    """On a Ready Player Me head (no NORMAL deltas in the file: derived per morph), the
    renderer turns each skin normal by as much as the deformed shape turns (its welded
    smooth normals, rest to now). The sum of per-morph deltas does not add up under a
    combined mix: 19.7 degrees off at p99 (54.7 at worst) before, 1.4 now."""
    rig = import_glb(shared_character("rpm_female_arkit_visemes.glb"))
    assert rig.normals_from_shape
    w = np.zeros(rig.n_morphs, np.float32)
    for name, value in RPM_SMILE.items():
        w[rig.morph_index(name)] = value
    positions, normals = Deformer(rig)(rig.bone_rest, w)
    ref_positions, ref_normals = deform(rig, rig.bone_rest, w)
    # float32 positions against the reference's float64: tiny triangles turn by ~1e-4
    assert np.abs(ref_normals - normals).max() < 1e-3 and np.abs(ref_positions - positions).max() < 1e-4
    moved = np.abs(rig.morph_positions[w > 0]).max(axis=(0, 2)) > 0
    skin = (np.asarray(rig.material) == 0) & moved
    shape_turn = _angles(_welded_normals(rig, positions), _welded_normals(rig, rig.vertices))[skin]
    error = np.abs(_angles(normals, rig.normals)[skin] - shape_turn)
    assert skin.sum() > 1000 and np.percentile(shape_turn, 95) > 10.0  # the mix does turn the cheeks
    assert np.percentile(error, 99) < 3.0 and error.max() < 10.0


def test_the_builtin_avatar_keeps_its_morph_normals(avatar):
    """The built-in avatar (its own exact morph normals) is drawn as before."""
    assert not avatar.normals_from_shape


def test_mask_lashes_draw_only_their_opaque_texels(ict):
    """The eyelash cards are MASK: with an all-transparent alpha they draw nothing (the
    image of the head without them); with their own alpha they draw far fewer pixels than
    as opaque cards, and some."""
    assert ict.alpha is not None and (ict.alpha_mode == 1).sum() > 500
    lash_tris = ict.alpha_mode[ict.triangles[:, 2]] == 1
    without = _render(ict.replace(triangles=ict.triangles[~lash_tris]), eyes=True)
    assert np.array_equal(_render(ict.replace(alpha=np.zeros_like(ict.alpha)), eyes=True), without)
    cards, lashes = ((np.abs(_render(rig, eyes=True).astype(int) - without.astype(int)).max(2) > 12).sum()
                     for rig in (ict.replace(alpha_mode=np.zeros_like(ict.alpha_mode)), ict))
    assert cards > 800
    assert 0.05 * cards < lashes < 0.6 * cards


def test_blend_draws_over_what_is_behind():
    """BLEND: the built-in avatar's eyes at alpha 128 show half themselves, half the eye
    socket behind them: drawn after the opaque geometry, blended, whatever their place in
    the index."""
    avatar = default_avatar()
    eye = avatar.material == 1
    blended = avatar.replace(alpha=np.full(avatar.albedo.shape[:2], 128, np.uint8),
                             alpha_mode=np.where(eye, 2, 0).astype(np.uint8),
                             alpha_cutoff=np.full(avatar.n_vertices, 0.5, np.float32))
    eye_tris = eye[avatar.triangles[:, 2]]
    order = np.concatenate([np.flatnonzero(eye_tris), np.flatnonzero(~eye_tris)])  # eyes first in the index
    opaque = _render(avatar, eyes=True).astype(float)
    behind = _render(avatar.replace(triangles=avatar.triangles[~eye_tris]), eyes=True).astype(float)
    image = _render(blended.replace(triangles=avatar.triangles[order]), eyes=True).astype(float)
    where = np.abs(opaque - behind).max(2) > 40  # the eyes' pixels
    assert where.sum() > 1000
    mix = (128 / 255) * opaque + (1 - 128 / 255) * behind
    assert np.percentile(np.abs(image - mix)[where], 99) <= 2.0


def test_unreadable_texture_draws_the_base_colour_factor_with_a_warning(tmp_path_factory, ict, caplog):
    """A texture that cannot be read (here a KTX2 file that is not beside the .glb): the
    character loads, that material takes its base colour factor, one warning names the
    image."""
    def lose(gltf):
        gltf.images[1].bufferView = None
        gltf.images[1].uri = "sclera.ktx2"
        gltf.images[1].mimeType = "image/ktx2"

    with caplog.at_level(logging.WARNING, logger="capture2face"):
        rig = import_glb(_variant(tmp_path_factory, "lost_texture.glb", lose))
    said = [r.getMessage() for r in caplog.records if "sclera" in r.getMessage()]
    assert len(said) == 1 and "sclera.ktx2' is missing" in said[0] and "base colour factor" in said[0]
    eyes = (rig.material == 1) & (rig.alpha_mode == 0)  # sclera (white factor) and iris

    def colours(r):
        texels = r.albedo[(r.uvs[eyes, 1] * r.albedo.shape[0]).astype(int),
                          (r.uvs[eyes, 0] * r.albedo.shape[1]).astype(int)]
        return np.unique(texels, axis=0)

    assert len(colours(ict)) > 20
    assert len(colours(rig)) == 2 and [255, 255, 255] in colours(rig).tolist()
    assert np.array_equal(rig.vertices, ict.vertices)


def test_alpha_survives_save_load_and_gltf_export(tmp_path, ict):
    """FaceRig.save/load and the .glb export keep the alpha, its modes and cutoffs; the
    export has one primitive per alpha group with glTF's alphaMode."""
    ict.save(tmp_path / "ict.npz")
    back = FaceRig.load(tmp_path / "ict.npz")
    for name in ("alpha", "alpha_mode", "alpha_cutoff"):
        assert np.array_equal(getattr(back, name), getattr(ict, name))
    export_glb(ict, tmp_path / "ict.glb")
    gltf = pygltflib.GLTF2().load(str(tmp_path / "ict.glb"))
    assert [m.alphaMode for m in gltf.materials] == ["OPAQUE", "MASK"]
    again = import_glb(tmp_path / "ict.glb")
    for name in ("alpha", "alpha_mode", "alpha_cutoff", "albedo"):
        assert np.array_equal(getattr(again, name), getattr(ict, name))

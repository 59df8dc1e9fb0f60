"""glTF 2.0 (.glb) export and import of FaceRigs (issue 2, item 5)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from capture2face.character.load import import_glb
from capture2face.errors import CaptureError
from capture2face.gltf import export_glb
from capture2face.gltf.container import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GlbBuilder, GlbReader, encode_png
from tests.helpers import problems, validate


@pytest.fixture(scope="module")
def avatar_glb(avatar, tmp_path_factory):
    path = tmp_path_factory.mktemp("glb") / "avatar.glb"
    export_glb(avatar, path)
    return path


def test_avatar_glb_passes_khronos_validator(avatar, avatar_glb):
    report = validate(avatar_glb)
    assert report["issues"]["numErrors"] == 0, problems(report, 0)
    assert report["issues"]["numWarnings"] == 0, problems(report, 1)
    info = report["info"]
    assert info["animationCount"] == 0 and info["hasSkins"] and info["hasMorphTargets"]
    assert info["totalVertexCount"] == avatar.n_vertices and info["maxInfluences"] == 4


def test_avatar_glb_round_trip_within_1e6(avatar, avatar_glb):
    back = import_glb(avatar_glb)
    # Geometry, skin and morphs within 1e-6 (cm): float32 through metres costs <= 1 ulp
    # (of the cm value: < 2e-6 out to the neck's 27 cm, < 1e-6 on the face).
    assert back.vertices.shape == avatar.vertices.shape
    assert np.all(np.abs(back.vertices - avatar.vertices) <= np.spacing(np.abs(avatar.vertices)))
    face = avatar.material == 0
    assert np.abs(back.vertices[face] - avatar.vertices[face]).max() <= 1e-6
    assert np.abs(back.uvs - avatar.uvs).max() <= 1e-6
    assert np.abs(back.dense_skin_weights() - avatar.dense_skin_weights()).max() <= 1e-6
    assert np.abs(back.morph_positions - avatar.morph_positions).max() <= 1e-6
    assert np.abs(back.morph_normals - avatar.morph_normals).max() <= 1e-6
    assert np.abs(back.normals - avatar.normals).max() <= 1e-6
    assert np.abs(back.tangents - avatar.tangents).max() <= 1e-6
    np.testing.assert_array_equal(back.triangles, avatar.triangles)
    # Everything glTF has no slot for comes back exactly from extras / custom attributes.
    for name in ("bone_rest", "bone_parents", "bone_landmarks", "bone_groups", "landmark_vertices",
                 "position_ids", "material", "pose_bones", "pose_morph_weights", "pose_maps",
                 "zone_table", "region_weights", "albedo", "normal_map", "wrinkle_maps", "zone_masks"):
        np.testing.assert_array_equal(getattr(back, name), getattr(avatar, name), err_msg=name)
    for name in ("bone_names", "morph_names", "pose_names", "wrinkle_map_names", "zone_names", "region_names"):
        assert getattr(back, name) == getattr(avatar, name), name


def test_glb_layout_is_metres_with_named_targets_and_translation_ibms(avatar, avatar_glb):
    r = GlbReader(avatar_glb)
    g = r.gltf
    prim = g["meshes"][0]["primitives"][0]
    assert g["meshes"][0]["extras"]["targetNames"] == avatar.morph_names
    pos = r.accessor(prim["attributes"]["POSITION"])
    np.testing.assert_allclose(pos * 100.0, avatar.vertices, atol=1e-5)
    assert g["accessors"][prim["attributes"]["JOINTS_0"]]["componentType"] == 5121  # unsigned byte
    w = r.accessor(prim["attributes"]["WEIGHTS_0"])
    assert np.abs(w.sum(1) - 1).max() < 2e-7
    # Joints: the bones, then the two eye joints at the eye centres.
    joint_rest = np.vstack([avatar.bone_rest, avatar.eye_centres])
    ibm = r.accessor(g["skins"][0]["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    np.testing.assert_allclose(ibm[:, :3, 3] * 100.0, -joint_rest, atol=1e-5)
    np.testing.assert_allclose(ibm[:, :3, :3], np.tile(np.eye(3), (len(joint_rest), 1, 1)))
    # Joint nodes: parent-relative translations compose to the rest positions.
    nodes = g["nodes"]
    joints = g["skins"][0]["joints"]
    assert [nodes[j]["name"] for j in joints[avatar.n_bones:]] == ["eye_R", "eye_L"]
    eye_joint = r.accessor(prim["attributes"]["JOINTS_0"])[avatar.eye_vertex_side >= 0, 0]
    np.testing.assert_array_equal(eye_joint, avatar.n_bones + avatar.eye_vertex_side[avatar.eye_vertex_side >= 0])
    parent = {c: p for p, n in enumerate(nodes) for c in n.get("children", [])}
    for b, j in enumerate(joints):
        total, n = np.zeros(3), j
        while n in joints:
            total += nodes[n]["translation"]
            n = parent[n]
        np.testing.assert_allclose(total * 100.0, joint_rest[b], atol=1e-4)
    assert nodes[joints[0]]["name"] == "head"


def test_cli_avatar_export_writes_a_valid_glb(tmp_path, avatar):
    from capture2face.cli import main

    out = tmp_path / "cli_avatar.glb"
    assert main(["-q", "avatar", "--export", str(out)]) == 0
    back = import_glb(out)
    assert back.n_vertices == avatar.n_vertices and back.morph_names == avatar.morph_names


# ---- a foreign character: what a user brings ------------------------------------------
def _foreign_glb(tmp_path):
    """A hand-built character as another tool might write it: two primitives with their
    own vertices (skin + an eye material), no normals or tangents, WEIGHTS_0 as
    normalized unsigned bytes, a sparse morph target, joints under an 'Armature' node
    named Head / BrowL / BrowR / Jaw / Lip, positions in metres."""
    rng = np.random.default_rng(3)
    n = 9
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    skin = np.stack([0.07 * u, 0.09 * v, 0.05 * np.cos(u) * np.cos(v)], -1).reshape(-1, 3).astype(np.float32)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]).astype(np.uint16)
    uvs = np.stack([(u + 1) / 2, (1 - v) / 2], -1).reshape(-1, 2).astype(np.float32)
    eye = (skin[:4] * 0.2 + [0.03, 0.02, 0.05]).astype(np.float32)
    eye_tris = np.array([[0, 1, 2], [1, 3, 2]], np.uint16)
    bones_m = np.array([[0, 0, 0], [0.03, 0.04, 0.05], [-0.03, 0.04, 0.05], [0, -0.07, 0.04], [0, -0.03, 0.06]])
    dist = np.linalg.norm(skin[:, None] - bones_m[None, 1:], axis=2)
    w = np.concatenate([np.full((len(skin), 1), 0.2), np.exp(-(dist / 0.03) ** 2)], 1)
    top = np.argsort(-w, 1)[:, :4]
    wt = np.take_along_axis(w, top, 1)
    wt /= wt.sum(1, keepdims=True)
    w8 = np.round(wt * 255).astype(np.int64)
    w8[:, 0] += 255 - w8.sum(1)  # normalized ubyte rows must sum to 255
    bld = GlbBuilder(generator="test")
    sparse_idx = np.array([3, 40, 77], np.uint16)
    sparse_val = np.array([[0, 0.01, 0], [0, 0, 0.02], [0.005, 0, 0]], np.float32)
    prims = []
    for pos, tri, uv, joints, weights, mat in (
        (skin, tris, uvs, top.astype(np.uint8), w8.astype(np.uint8), 0),
        (eye, eye_tris, uvs[:4], np.zeros((4, 4), np.uint8), np.array([[255, 0, 0, 0]] * 4, np.uint8), 1),
    ):
        attrs = {
            "POSITION": bld.accessor(pos, ARRAY_BUFFER, minmax=True),
            "TEXCOORD_0": bld.accessor(uv, ARRAY_BUFFER),
            "JOINTS_0": bld.accessor(joints, ARRAY_BUFFER),
            "WEIGHTS_0": bld.accessor(weights, ARRAY_BUFFER, normalized=True),
        }
        if mat == 0:
            target = {"bufferView": None, "componentType": 5126, "count": len(pos), "type": "VEC3",
                      "min": [0, 0, 0], "max": [0.005, 0.01, 0.02],
                      "sparse": {"count": 3,
                                 "indices": {"bufferView": bld.buffer_view(sparse_idx.tobytes()),
                                             "componentType": 5123},
                                 "values": {"bufferView": bld.buffer_view(sparse_val.tobytes())}}}
            del target["bufferView"]
            targets = [{"POSITION": bld.add("accessors", target)}]
        else:
            targets = [{"POSITION": bld.accessor(np.zeros_like(pos), ARRAY_BUFFER, minmax=True)}]
        prims.append({"attributes": attrs, "indices": bld.accessor(tri.ravel(), ELEMENT_ARRAY_BUFFER),
                      "material": mat, "targets": targets})
    albedo = rng.integers(0, 255, (16, 16, 3), dtype=np.uint8)
    img = bld.image_png(albedo, "albedo")
    tex = bld.add("textures", {"source": img})
    bld.add("materials", {"name": "Skin", "pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}})
    bld.add("materials", {"name": "EyeBall", "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1]}})
    mesh = bld.add("meshes", {"primitives": prims, "extras": {"targetNames": ["JawOpen"]}})
    names = ["Head", "BrowL", "BrowR", "Jaw", "Lip"]
    first = 2
    bld.add("nodes", {"name": "Body", "mesh": mesh, "skin": 0})
    bld.add("nodes", {"name": "Armature", "children": [first]})
    for i, nm in enumerate(names):
        node = {"name": nm, "translation": (bones_m[i] - (bones_m[0] if i else 0)).tolist()}
        if i == 0:
            node["children"] = [first + k for k in range(1, 4)]
        if i == 3:
            node["children"] = [first + 4]
            node["translation"] = (bones_m[3] - bones_m[0]).tolist()
        if i == 4:
            node["translation"] = (bones_m[4] - bones_m[3]).tolist()
        bld.add("nodes", node)
    ibm = np.tile(np.eye(4, dtype=np.float32), (5, 1, 1))
    ibm[:, 3, :3] = -bones_m
    bld.add("skins", {"joints": [first + i for i in range(5)],
                      "inverseBindMatrices": bld.accessor(ibm.reshape(5, 16), gltf_type="MAT4")})
    bld.gltf["scenes"] = [{"nodes": [0, 1]}]
    path = tmp_path / "character.glb"
    path.write_bytes(bld.to_bytes())
    maps = tmp_path / "maps"
    maps.mkdir()
    stretch = np.zeros((8, 8, 3), np.uint8)
    stretch[:] = (128, 160, 240)
    (maps / "stretch.png").write_bytes(encode_png(stretch))
    mapping = {
        "name": "user_char",
        "head_bone": "Head",
        "bones": {"BrowL": 336, "BrowR": 107, "Jaw": 152, "Lip": 13},
        "bone_groups": [["BrowL", "BrowR"]],
        "wrinkle_maps": {"stretch": "maps/stretch.png"},
        "poses": {"stretch": {"offsets": {"BrowL": [0, 1.0, 0], "BrowR": [0, 1.0, 0]}, "morphs": {"JawOpen": 0.5}},
                  "compress": {"positions": {"BrowL": [2.5, 3.0, 5.0]}}},
        "zone_table": {"jawopen": [0, 0, 0, 0, 0, 0.5, 0.5, 1]},
    }
    (tmp_path / "character.json").write_text(json.dumps(mapping))
    return path, {"skin": skin, "eye": eye, "bones_m": bones_m, "albedo": albedo, "wt": wt, "top": top,
                  "sparse_idx": sparse_idx, "sparse_val": sparse_val}


def test_import_foreign_character_with_mapping(tmp_path):
    from capture2face.gltf.rig_import import import_glb as import_raw  # the avatar's loans: tested below

    path, src = _foreign_glb(tmp_path)
    rig = import_raw(path)  # mapping found beside the .glb
    V = len(src["skin"]) + len(src["eye"])
    assert rig.name == "user_char" and rig.n_vertices == V and len(rig.triangles) == 2 * 64 + 2
    np.testing.assert_allclose(rig.vertices[: len(src["skin"])], src["skin"] * 100, atol=1e-5)
    np.testing.assert_array_equal(rig.material, [0] * len(src["skin"]) + [1] * 4)  # "EyeBall" -> eye
    assert rig.bone_names == ["head", "BrowL", "BrowR", "Jaw", "Lip"]
    np.testing.assert_array_equal(rig.bone_parents, [-1, 0, 0, 0, 3])
    np.testing.assert_allclose(rig.bone_rest, src["bones_m"] * 100, atol=1e-4)
    np.testing.assert_array_equal(rig.bone_landmarks, [-1, 336, 107, 152, 13])
    assert rig.bone_groups[1] == rig.bone_groups[2] and len(set(rig.bone_groups.tolist())) == 4
    # Skin weights: convex, the ubyte-normalized values of the file (to 1/255).
    assert np.abs(rig.skin_weights.sum(1) - 1).max() < 1e-6 and rig.skin_weights.min() >= 0
    dense = rig.dense_skin_weights()[: len(src["skin"])]
    expect = np.zeros_like(dense)
    np.put_along_axis(expect, src["top"], src["wt"], 1)
    assert np.abs(dense - expect).max() < 1.5 / 255
    # The sparse morph target, in cm; computed normals and tangents are unit.
    assert rig.morph_names == ["JawOpen"]
    expect_delta = np.zeros((V, 3))
    expect_delta[src["sparse_idx"]] = src["sparse_val"] * 100
    np.testing.assert_allclose(rig.morph_positions[0], expect_delta, atol=1e-5)
    assert np.abs(np.linalg.norm(rig.normals, axis=1) - 1).max() < 1e-5
    assert np.abs(np.linalg.norm(rig.tangents[:, :3], axis=1) - 1).max() < 1e-5
    assert rig.normals[: len(src["skin"]), 2].mean() > 0.5  # faces +z, as the winding says
    # Textures: albedo from the skin material; the stretch map read and resized; the
    # compress map and the base normal map flat; zone masks zero.
    np.testing.assert_array_equal(rig.albedo, src["albedo"])
    assert rig.wrinkle_map_names == ["stretch", "compress"]
    assert rig.wrinkle_maps.shape == (2, 16, 16, 3)
    np.testing.assert_array_equal(rig.wrinkle_maps[0, 5, 5], [128, 160, 240])
    np.testing.assert_array_equal(rig.wrinkle_maps[1, 5, 5], [128, 128, 255])
    assert rig.zone_masks.shape == (16, 16, 8) and rig.zone_masks.max() == 0
    # Poses: offsets and absolute positions in cm; other bones at rest.
    s, c = rig.pose_index("stretch"), rig.pose_index("compress")
    np.testing.assert_allclose(rig.pose_bones[s, 1] - rig.bone_rest[1], [0, 1, 0], atol=1e-5)
    np.testing.assert_allclose(rig.pose_bones[c, 1], [2.5, 3.0, 5.0], atol=1e-6)
    np.testing.assert_allclose(rig.pose_bones[s, 3], rig.bone_rest[3])
    assert rig.pose_morph_weights[s, 0] == 0.5
    assert rig.pose_maps[s] == 0 and rig.pose_maps[c] == 1
    np.testing.assert_allclose(rig.zone_table[0], [0, 0, 0, 0, 0, 0.5, 0.5, 1])


def test_import_foreign_character_lends_defaults_from_avatar(tmp_path, avatar):
    path, _ = _foreign_glb(tmp_path)
    bare = tmp_path / "bare.json"  # bones only: poses, zone table, regions lent by the avatar
    bare.write_text(json.dumps({"head_bone": "Head", "bones": {"BrowL": 336, "BrowR": 107, "Jaw": 152, "Lip": 13}}))
    rig = import_glb(path, bare)
    # Regions: the vertex halfway between the lip (landmark 13) and the chin-bottom bone
    # (landmark 152) lies in the chin region, not in the forehead.
    chin = rig.region_names.index("chin")
    mid = np.argmin(np.linalg.norm(rig.vertices - 0.5 * (rig.bone_rest[3] + rig.bone_rest[4]), axis=1))
    assert rig.region_weights[chin, mid] > 0.5
    assert rig.region_weights[rig.region_names.index("forehead"), mid] == 0
    assert (rig.landmark_vertices >= 0).sum() >= 400
    # Poses: each bone moves like the avatar's bone on the same landmark (scaled by the fit).
    for pose in ("stretch", "compress"):
        p, ap = rig.pose_index(pose), avatar.pose_index(pose)
        for b, lm in ((1, 336), (3, 152)):
            ab = int(np.flatnonzero(avatar.bone_landmarks == lm)[0])
            ours = rig.pose_bones[p, b] - rig.bone_rest[b]
            theirs = avatar.pose_bones[ap, ab] - avatar.bone_rest[ab]
            assert np.linalg.norm(ours) > 0.2 * np.linalg.norm(theirs) > 0
            cos = ours @ theirs / (np.linalg.norm(ours) * np.linalg.norm(theirs))
            assert cos > 0.7, (pose, b, cos)
    # Zone table row by morph name (case-insensitive: "JawOpen" <- avatar "jawOpen").
    np.testing.assert_array_equal(rig.zone_table[0], avatar.zone_table[avatar.morph_index("jawOpen")])


def test_glb_without_skin_or_morphs_is_an_error(tmp_path):
    bld = GlbBuilder()
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    bld.add("meshes", {"primitives": [{"attributes": {"POSITION": bld.accessor(pos, ARRAY_BUFFER, minmax=True)}}]})
    bld.add("nodes", {"mesh": 0})
    bld.gltf["scenes"] = [{"nodes": [0]}]
    path = tmp_path / "static.glb"
    path.write_bytes(bld.to_bytes())
    with pytest.raises(CaptureError, match="no skinned mesh and no morph targets"):
        import_glb(path)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "bad_json", "missing"])
def test_corrupt_glb_is_a_capture_error(tmp_path, avatar_glb, damage):
    data = avatar_glb.read_bytes()
    path = tmp_path / f"{damage}.glb"
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 3])
    elif damage == "garbage":
        path.write_bytes(np.random.default_rng(0).integers(0, 255, 5000, dtype=np.uint8).tobytes())
    elif damage == "bad_json":
        path.write_bytes(data[:20] + b"{{{{" + data[24:])
    with pytest.raises(CaptureError) as err:
        import_glb(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_mapping_errors_are_one_line(tmp_path):
    path, _ = _foreign_glb(tmp_path)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"bones": {"NoSuchBone": 10}}))
    with pytest.raises(CaptureError, match="NoSuchBone"):
        import_glb(path, bad)
    with pytest.raises(CaptureError, match="mapping file not found"):
        import_glb(path, tmp_path / "absent.json")

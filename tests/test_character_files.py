"""Odd character files through the command line, as a user types them (issue 33): a node
that is its own child, textures that cannot be read, a .gltf folder missing a PNG, a
mapping naming a morph the file lacks, a head that gets no automatic wrinkles. A failure
is exit 2 and one line naming the cause, before tracking; a warning is printed as
``capture2face: warning: ...`` and kept in report.json; never a traceback."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest

from tests.helpers import REPO, SAMPLE, rewrite, run_cli, unique

FOLDER = REPO / "tests" / "data" / "real_files" / "folder"
KTX2_MAGIC = b"\xabKTX 20\xbb\r\n\x1a\n"


def failed_in_one_line(result: subprocess.CompletedProcess, *mentions: str) -> str:
    assert result.returncode == 2, (result.returncode, result.stderr[-3000:])
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("capture2face: error: "), result.stderr[-3000:]
    assert "Traceback" not in result.stderr
    for m in mentions:
        assert m in lines[0], lines[0]
    return lines[0]


def warnings_of(result: subprocess.CompletedProcess) -> list[str]:
    """The run's stderr: every line a ``capture2face: warning:`` (no traceback, no bare
    message, no NumPy RuntimeWarning)."""
    assert result.returncode == 0, result.stderr[-3000:]
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    stray = [ln for ln in lines if not ln.startswith("capture2face: warning: ")]
    assert not stray, result.stderr[-3000:]
    return [ln[len("capture2face: warning: "):] for ln in lines]


# ---- item 1: a node that is its own child ------------------------------------------------
@pytest.mark.parametrize("children", [[[0]], [[1], [0]]], ids=["own-child", "two-node-loop"])
def test_node_cycle_fails_in_one_line_before_tracking(hero, tmp_path, children):
    def loop(gltf, _):
        for i, c in enumerate(children):
            gltf["nodes"][i]["children"] = c

    glb = rewrite(hero, tmp_path / "loop.glb", loop)
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), timeout=120)
    line = failed_in_one_line(result, str(glb), "node 0", "cycle")
    assert "Recursion" not in line
    assert not (tmp_path / "out").exists()


def test_node_with_a_child_out_of_range_fails_in_one_line(hero, tmp_path):
    glb = rewrite(hero, tmp_path / "far.glb", lambda g, _: g["nodes"][0].update(children=[99]))
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), timeout=120)
    failed_in_one_line(result, str(glb), "node 0", "99")


# ---- item 6: a mapping naming a morph the file does not have ------------------------------
@pytest.mark.parametrize("morphs,named,closest", [
    ({"NoSuchMorph": "jawOpen"}, "NoSuchMorph", None),
    ({"jawOpn": "jawOpen"}, "jawOpn", "jawOpen"),  # a typo: the closest names are offered
    ({"mouthSmile_L": "mouthSmileLeft", "browinnerup": "browInnerUp"}, "browinnerup", "browInnerUp"),
])
def test_mapping_morph_the_file_lacks_fails_before_tracking(hero, tmp_path, morphs, named, closest):
    glb = rewrite(hero, tmp_path / "hero.glb", lambda g, _: None)
    (tmp_path / "hero.json").write_text(json.dumps({"morphs": morphs}))
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), timeout=120)
    line = failed_in_one_line(result, str(tmp_path / "hero.json"), f"'{named}'", "no morph")
    if closest:
        assert f"'{closest}'" in line.split("closest")[1], line
    assert not (tmp_path / "out").exists()



@pytest.mark.slow
def test_a_mapping_warning_is_said_once(hero, tmp_path):
    """A key the mapping schema lacks is warned about once, on screen and in report.json,
    though the mapping is read at the checks and again at the export."""
    glb = rewrite(hero, tmp_path / "hero.glb", lambda g, _: None)
    (tmp_path / "hero.json").write_text(json.dumps({"morph": {"NoSuchMorph": "jawOpen"}}))
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), "--size", "64",
                 timeout=300)
    said = warnings_of(result)
    assert sum("ignored keys" in w and "'morph'" in w for w in said) == 1, said
    assert json.loads((tmp_path / "out" / "sample" / "report.json").read_text())["warnings"] == said


# ---- item 7: a head that gets no automatic wrinkles ---------------------------------------
def _no_pose_morphs(gltf, _):
    """The brow, eye and nose morphs renamed out of ARKit's names: the head is still
    driven (jaw, mouth) but has nothing to make its wrinkle reference poses from."""
    for mesh in gltf["meshes"]:
        names = (mesh.get("extras") or {}).get("targetNames")
        if names:
            mesh["extras"]["targetNames"] = [f"custom_{k}" if n.startswith(("brow", "eye", "nose")) else n
                                             for k, n in enumerate(names)]


NO_WRINKLES = "no automatic wrinkles: character 'plain'"


def test_no_automatic_wrinkles_is_said_on_every_run(hero, tmp_path):
    """First run (the character prepared), second run (read from the cache): the same
    warning, with the prefix, on screen and in report.json."""
    glb = rewrite(hero, tmp_path / "plain.glb", _no_pose_morphs)
    for name in ("first", "cached"):
        result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--name", name, "--character", str(glb),
                     "--size", "64", timeout=300)
        said = warnings_of(result)
        assert sum(NO_WRINKLES in w for w in said) == 1, (name, said)
        report = json.loads((tmp_path / "out" / name / "report.json").read_text())
        assert sum(NO_WRINKLES in w for w in report["warnings"]) == 1, (name, report["warnings"])


def test_no_automatic_wrinkles_in_a_batch(hero, tmp_path):
    """batch --jobs 2: said once on screen with the prefix (the batch's check), and in each
    clip's report.json (its worker's)."""
    glb = rewrite(hero, tmp_path / "plain.glb", _no_pose_morphs)
    clips = tmp_path / "clips"
    clips.mkdir()
    for name in ("a.mp4", "b.mp4"):
        shutil.copy(SAMPLE, clips / name)
    result = run_cli("batch", str(clips), "-o", str(tmp_path / "out"), "--jobs", "2", "--character", str(glb),
                 "--size", "64", timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    lines = [ln for ln in result.stderr.splitlines() if NO_WRINKLES in ln]
    assert len(lines) == 1 and lines[0].startswith("capture2face: warning: "), result.stderr[-3000:]
    assert "RuntimeWarning" not in result.stderr and "Traceback" not in result.stderr
    for name in ("a", "b"):
        report = json.loads((tmp_path / "out" / name / "report.json").read_text())
        assert sum(NO_WRINKLES in w for w in report["warnings"]) == 1, report["warnings"]


# ---- item 2: a texture that cannot be read, in every stage --------------------------------
def _ktx2_undeclared(drop_uvs: bool):
    """Every image a KTX2 payload that does not transcode, used as the plain ``source``
    without ``KHR_texture_basisu`` declared (as a Face Cap head from a portfolio site has it);
    ``drop_uvs``: no TEXCOORD_0 either, so the face covers no texel of the texture (the
    automatic-wrinkle bake had nothing to sample: cv2.remap with an empty map)."""
    def change(gltf, binary):
        for image in gltf["images"]:
            data = KTX2_MAGIC + b"\0" * 68 + os.urandom(64)
            binary.extend(b"\0" * (-len(binary) % 4))
            gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
            binary.extend(data)
            image.update(bufferView=len(gltf["bufferViews"]) - 1, mimeType="image/ktx2")
        for mesh in gltf["meshes"] if drop_uvs else []:
            for prim in mesh["primitives"]:
                prim["attributes"].pop("TEXCOORD_0", None)
                prim["attributes"].pop("TANGENT", None)
    return change


@pytest.mark.slow
@pytest.mark.parametrize("drop_uvs", [True, False], ids=["no-uvs", "uvs"])
def test_unreadable_texture_runs_with_one_warning_per_image(hero, tmp_path, drop_uvs):
    glb = rewrite(hero, tmp_path / "facecap.glb", _ktx2_undeclared(drop_uvs))
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), "--size", "64",
                 timeout=300)
    said = warnings_of(result)
    for image in ("face_albedo", "face_normal"):
        assert sum(f"(image '{image}')" in w for w in said) == 1, said
    assert sum("no automatic wrinkles" in w for w in said) == int(drop_uvs), said
    folder = tmp_path / "out" / "sample"
    assert json.loads((folder / "report.json").read_text())["warnings"] == said
    assert (folder / "animation.glb").stat().st_size > 0 and (folder / "avatar.mp4").stat().st_size > 0



def _empty_images(gltf, binary):
    """Every image an empty buffer view (zero bytes): OpenCV's decoder asserted on it."""
    for image in gltf["images"]:
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": 0})
        image.update(bufferView=len(gltf["bufferViews"]) - 1, mimeType="image/png")


@pytest.mark.slow
def test_an_empty_image_runs_with_one_warning_per_image(hero, tmp_path):
    glb = rewrite(hero, tmp_path / "empty.glb", _empty_images)
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), "--size", "64",
                 timeout=300)
    said = warnings_of(result)
    for image in ("face_albedo", "face_normal"):
        assert sum(f"(image '{image}')" in w and "no bytes" in w for w in said) == 1, said


# ---- item 3: a .gltf folder with one PNG deleted ------------------------------------------
@pytest.mark.slow
def test_gltf_folder_missing_a_png_runs_with_its_base_colour(tmp_path):
    """Said at the checks, before tracking (one warning naming the PNG), drawn with the
    material's base colour, and animation.glb written (self-contained, that image white so
    the material shows its base colour factor there too)."""
    from capture2face.gltf.container import GlbReader, read_gltf_document

    folder = tmp_path / "character"
    shutil.copytree(FOLDER, folder)
    gltf = json.loads((folder / "character.gltf").read_text())
    (folder / "character.gltf").write_text(json.dumps(unique(gltf)))
    (folder / "baseColor_1.png").unlink()
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(folder / "character.gltf"),
                 "--size", "64", timeout=300)
    said = warnings_of(result)
    missing = [w for w in said if "baseColor_1.png" in w]
    assert len(missing) == 1 and "is missing" in missing[0] and "base colour" in missing[0], said
    out = tmp_path / "out" / "sample"
    assert json.loads((out / "report.json").read_text())["warnings"] == said
    doc, _ = read_gltf_document(out / "animation.glb")
    assert not any("uri" in x for x in doc.get("images", []) + doc.get("buffers", []))
    lost = GlbReader(out / "animation.glb").image(0)
    assert lost.shape[:2] == (1, 1) and (lost[..., :3] == 255).all()
    assert GlbReader(out / "animation.glb").image(1).shape[:2] != (1, 1)  # the others kept as they are



def test_gltf_folder_with_a_short_bin_names_it(tmp_path):
    """A .bin cut short (a copy that stopped): the line names the .bin and its size."""
    folder = tmp_path / "character"
    shutil.copytree(FOLDER, folder)
    (folder / "character.bin").write_bytes((folder / "character.bin").read_bytes()[:1000])
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(folder / "character.gltf"),
                 timeout=120)
    failed_in_one_line(result, "'character.bin'", "1000 bytes")
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_gltf_folder_with_an_unreadable_png_names_it(tmp_path):
    """A PNG beside the .gltf overwritten with text: the warning names that file."""
    folder = tmp_path / "character"
    shutil.copytree(FOLDER, folder)
    gltf = json.loads((folder / "character.gltf").read_text())
    (folder / "character.gltf").write_text(json.dumps(unique(gltf)))
    (folder / "baseColor_2.png").write_text("not a picture")
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(folder / "character.gltf"),
                 "--size", "64", timeout=300)
    said = warnings_of(result)
    assert sum("('baseColor_2.png') is unreadable" in w for w in said) == 1, said


@pytest.mark.slow
def test_no_skin_under_the_landmarks_gets_no_wrinkles_without_numpy_warnings(hero, tmp_path):
    """A mapping that marks the face as eye: no landmark lands on skin (the median depth of
    none was a NumPy RuntimeWarning, and the renderer's face size a ValueError); the head is
    still driven, with one warning."""
    glb = rewrite(hero, tmp_path / "eyeface.glb", lambda g, _: None)
    (tmp_path / "eyeface.json").write_text(json.dumps({"materials": {"Face": "eye"}}))
    result = run_cli("run", str(SAMPLE), "-o", str(tmp_path / "out"), "--character", str(glb), "--size", "64",
                 timeout=300)
    said = warnings_of(result)  # every line a prefixed warning: no RuntimeWarning
    assert sum("no automatic wrinkles: character 'eyeface'" in w for w in said) == 1, said

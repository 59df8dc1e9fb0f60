"""animation.glb plays in three.js (issue 14, item 5): ``tools/threejs_check/check.mjs``
loads a short run's animation.glb with three's GLTFLoader in headless Chromium, plays it
with an AnimationMixer and compares what three.js computes (morph influences, bone and
eye-joint transforms, skinned + morphed vertices, two rendered frames) with capture2face's
own figures (``Animation``, ``capture2face.rig.deform.deform``).

Needs node, /usr/bin/chromium and ``tools/threejs_check/node_modules``
(``cd tools/threejs_check && npm ci``); skips otherwise.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL = ROOT / "tools" / "threejs_check"
CHROMIUM = Path("/usr/bin/chromium")
SAMPLE = ROOT / "sample_videos" / "sample.mp4"


def _skip_reason() -> str | None:
    if shutil.which("node") is None:
        return "node not installed"
    if not CHROMIUM.is_file():
        return f"{CHROMIUM} not installed"
    for pkg in ("three", "playwright-core"):
        if not (TOOL / "node_modules" / pkg / "package.json").is_file():
            return f"{TOOL}/node_modules/{pkg} missing (cd tools/threejs_check && npm ci)"
    return None


pytestmark = pytest.mark.skipif(_skip_reason() is not None, reason=f"three.js check: {_skip_reason()}")


def check(glb: Path, expect: dict, *args: str) -> tuple[int, dict]:
    """Run check.mjs; (exit code, its JSON findings)."""
    path = glb.parent / f"expect_{len(args)}.json"
    path.write_text(json.dumps(expect))
    proc = subprocess.run(["node", str(TOOL / "check.mjs"), str(glb), "--expect", str(path), *args],
                          capture_output=True, text=True, timeout=600, cwd=TOOL)
    lines = proc.stdout.strip().splitlines()
    assert lines, f"check.mjs printed nothing: {proc.stderr}"
    return proc.returncode, json.loads(lines[-1])


@pytest.fixture(scope="module")
def run_out(tmp_path_factory) -> Path:
    """The bundled sample clip (120 frames, 30 fps) through ``run`` at 128 px."""
    from capture2face import run
    from capture2face.pipeline import RunOptions
    from capture2face.render import RenderOptions
    from capture2face.tracking import TrackOptions

    out = tmp_path_factory.mktemp("threejs")
    run(SAMPLE, out, RunOptions(render=RenderOptions(size=128), track=TrackOptions(workers=1), compare=False),
        progress=False)
    return out / "sample"


@pytest.fixture(scope="module")
def expected(run_out) -> dict:
    """What capture2face says animation.glb holds and how it moves, for check.mjs."""
    from capture2face.gltf import import_glb
    from capture2face.retarget.animation import Animation
    from capture2face.rig.deform import deform

    anim = Animation.load(run_out / "animation.npz")
    rig = import_glb(run_out / "animation.glb")  # the rig the file carries
    F = anim.n_frames
    src_b = {n: i for i, n in enumerate(anim.bone_names)}
    bones = np.repeat(rig.bone_rest[None].astype(np.float64), F, 0)
    for i, n in enumerate(rig.bone_names):
        if n in src_b:
            bones[:, i] = anim.bone_positions[:, src_b[n]]
    src_m = {n: i for i, n in enumerate(anim.blend_names)}
    weights = np.zeros((F, rig.n_morphs))
    for m, n in enumerate(rig.morph_names):
        if n in src_m:
            weights[:, m] = np.clip(anim.blend_weights[:, src_m[n]], 0, 1)
    gaze = np.nan_to_num(np.asarray(anim.eye_rotation, np.float64))
    positions, _ = deform(rig, bones, weights, gaze)  # (F, V, 3) cm, head coordinates

    # The frames to compare: first, last, the most expressive, the widest gaze, the most moved.
    moved = np.linalg.norm(positions - positions[0], axis=-1)  # (F, V)
    frames = sorted({0, F - 1, int(np.argmax(weights.sum(1))), int(np.argmax(np.abs(gaze).max(axis=(1, 2)))),
                     int(np.argmax(moved.max(1)))})
    # Vertices: the 150 that move most, 50 eyeball vertices, 100 spread over the mesh.
    eye_ids = np.flatnonzero(rig.eye_vertex_side >= 0)
    ids = np.unique(np.concatenate([np.argsort(moved.max(0))[-150:], eye_ids[:: max(1, len(eye_ids) // 50)],
                                    np.linspace(0, rig.n_vertices - 1, 100).astype(int)]))
    times = (np.asarray(anim.times, np.float64) - anim.times[0]).astype(np.float32)  # as the export writes them
    samples = [{
        "frame": k, "t": float(times[k]),
        "morph": {n: float(weights[k, m]) for m, n in enumerate(rig.morph_names)},
        "bones_cm": {n: bones[k, i].tolist() for i, n in enumerate(rig.bone_names)},
        "eyes_deg": gaze[k].tolist(),
        "vertices_cm": positions[k, ids].astype(np.float64).tolist(),
    } for k in frames]
    report = json.loads((run_out / "report.json").read_text())
    return {
        "morphs": rig.n_morphs, "joints": rig.n_bones + 2, "skinned_meshes": 1, "clips": 1, "keyframes": F,
        "duration": float(times[-1]),
        "tracks": {"position": rig.n_bones, "quaternion": 3, "morphTargetInfluences": 1},
        "eye_joints": ["eye_R", "eye_L"], "vertex_ids": ids.tolist(), "samples": samples,
        "render_times": [0.0, float(times[int(np.argmax(weights.sum(1)))])],
        "report": {"frames": report["frames"], "fps": report["fps"]},
    }


def test_animation_glb_plays_in_threejs(run_out, expected, tmp_path):
    shot = tmp_path / "threejs.png"
    code, found = check(run_out / "animation.glb", expected, "--screenshot", str(shot))
    assert code == 0 and found["ok"], found["failures"]
    # The run's figures: 120 frames at 30 fps -> one clip of 120 keys, 119 / 30 s long.
    frames, fps = expected["report"]["frames"], expected["report"]["fps"]
    assert frames == 120 and fps == 30.0
    assert found["keyframes"] == frames and found["duration"] == pytest.approx((frames - 1) / fps, abs=1e-5)
    # One skinned mesh, 27 named morphs, 26 bones + 2 eye joints; a position track per bone,
    # one morph-weights track, rotations of the head root and both eyes.
    assert found["skinned_meshes"] == 1 and found["morphs"] == 27 == expected["morphs"]
    assert found["morph_meshes"][0]["named"] == 27 and found["joints"] == 28
    assert found["tracks"] == {"position": 26, "morphTargetInfluences": 1, "quaternion": 3}
    assert found["eye_joints"] == ["eye_R", "eye_L"] and found["messages"] == []
    # It plays: everything moves between the sampled frames and stays finite ...
    assert found["all_finite"] and found["samples"] == len(expected["samples"]) >= 4
    assert found["moved"]["morph_influence"] > 0.2 and found["moved"]["bone_cm"] > 0.3
    assert found["moved"]["eye_deg"] > 2.0 and found["moved"]["turn_deg"] > 2.0
    assert found["moved"]["vertex_cm"] > 0.3 and found["moved"]["surface_cm"] > 1.0
    assert found["turned"] == ["capture2face_root (Object3D)", "eye_R (Bone)", "eye_L (Bone)"]
    # ... exactly as capture2face computes it (float32 keys, metres <-> cm).
    err = found["max_error"]
    assert err["morph"] <= 1e-6 and err["bone_cm"] <= 1e-4 and err["eye_deg"] <= 1e-3 and err["vertex_cm"] <= 1e-3
    # Two frames rendered (WebGL on SwiftShader): the head fills part of each, and they differ.
    r = found["render"]
    assert r["webgl"] == 2 and r["size"] == [768, 384]
    assert all(0.05 < d < 0.8 for d in r["drawn"]) and r["changed"] > 0.01
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_threejs_check_fails_on_a_wrong_file(run_out, expected):
    # The same file against wrong figures: one morph too many, a vertex moved by 1 cm.
    wrong = json.loads(json.dumps(expected))
    wrong["morphs"] += 1
    wrong["samples"][1]["vertices_cm"][0][1] += 1.0
    code, found = check(run_out / "animation.glb", wrong, "--no-render")
    assert code == 1 and not found["ok"] and "render" not in found
    assert any(f.startswith("morphs: three.js has 27, expected 28") for f in found["failures"])
    moved = [float(f.split(" by ")[1].split()[0]) for f in found["failures"] if f.startswith("vertex_cm differs")]
    assert len(moved) == 1 and moved[0] == pytest.approx(1.0, abs=1e-3)
    assert len(found["failures"]) == 2


def test_arkit_character_animation_glb_plays_in_threejs(tmp_path_factory):
    # A third-party-style character (head, eyes, mouth, teeth, scalp as separate meshes with
    # ARKit morphs, a Hips-Neck-Head skin, a body): its animation.glb is the user's file plus
    # a weights channel per morph mesh and the head joint's rotation.
    from capture2face import run
    from capture2face.gltf.arkit_export import export_arkit_character
    from capture2face.gltf.container import GlbReader
    from capture2face.pipeline import RunOptions, load_character
    from capture2face.render import RenderOptions
    from capture2face.tracking import TrackOptions

    folder = tmp_path_factory.mktemp("threejs_arkit")
    character = folder / "head.glb"
    export_arkit_character(load_character(None), character, skeleton=True, body=True)
    run(SAMPLE, folder, RunOptions(character=character, render=RenderOptions(size=128), track=TrackOptions(workers=1),
                   compare=False), progress=False)
    glb = folder / "sample" / "animation.glb"
    g = GlbReader(glb).gltf
    paths = [c["target"]["path"] for c in g["animations"][0]["channels"]]
    report = json.loads((folder / "sample" / "report.json").read_text())
    expect = {"morphs": sum(len(m["primitives"][0].get("targets", [])) for m in g["meshes"]),
              "joints": len(g["skins"][0]["joints"]), "skinned_meshes": sum("skin" in n for n in g["nodes"]),
              "clips": 1, "keyframes": report["frames"], "duration": (report["frames"] - 1) / report["fps"],
              "tracks": {"morphTargetInfluences": paths.count("weights"), "quaternion": paths.count("rotation")}}
    assert expect["morphs"] == 47 and expect["joints"] == 3 and expect["skinned_meshes"] == 6
    code, found = check(glb, expect, "--screenshot", str(folder / "shot.png"))
    assert code == 0 and found["ok"], found["failures"]
    assert [m["targets"] for m in found["morph_meshes"]] == [27, 14, 3, 3]  # head, mouth, teeth, scalp
    assert found["tracks"] == {"morphTargetInfluences": 4, "quaternion": 1} and found["keyframes"] == 120
    # The rotation binds to the Head joint, though a mesh node is also called "Head".
    assert found["turned"] == ["Head_1 (Bone)"] and found["messages"] == []
    assert found["moved"]["morph_influence"] > 0.2 and found["moved"]["turn_deg"] > 2.0
    assert found["moved"]["surface_cm"] > 1.0 and found["all_finite"]
    assert all(0.05 < d < 0.8 for d in found["render"]["drawn"]) and found["render"]["changed"] > 0.005

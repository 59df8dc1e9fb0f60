"""Plain helpers shared by the test files (fixtures live in conftest.py): the shared clips
and characters, synthetic tracks and performances made without the tracker, bad or cut
video files, and the Khronos glTF validator. Imported as ``from tests.helpers import ...``."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from capture2face.retarget.animation import Animation
from capture2face.rig.deform import deform
from capture2face.rig.face_rig import REGION_NAMES, ZONE_NAMES
from capture2face.topology import BLENDSHAPE_NAMES, IOD_PAIR, N_LANDMARKS
from capture2face.tracking import TrackOptions
from capture2face.tracking.filtering import one_euro
from capture2face.tracking.head_pose import canonical_mesh
from capture2face.tracking.track import Track

REPO = Path(__file__).resolve().parents[1]
SHARED_CLIPS = REPO.parent / "shared" / "clips"
SHARED_CHARACTERS = REPO.parent / "shared" / "characters"


# ---- shared clips and characters -------------------------------------------------------
def shared_clip(name: str) -> Path:
    """A real recorded clip from ../shared/clips; skips the test when it is absent."""
    path = SHARED_CLIPS / name
    if not path.is_file():
        pytest.skip(f"{path} not present (real clips live in ../shared/clips)")
    return path


def shared_character(name: str) -> Path:
    """A third-party head from ../shared/characters (ICT-FaceKit); skips the test when it
    is absent."""
    path = SHARED_CHARACTERS / name
    if not path.is_file():
        pytest.skip(f"{path} not present (third-party heads live in ../shared/characters)")
    return path


# ---- video files -----------------------------------------------------------------------
def truncated_copy(clip: Path, folder: Path) -> Path:
    """``clip`` remuxed with its index first (faststart), then cut at 60% of its bytes: a
    clip whose decoding fails part way, the way a download cut short does."""
    import av

    faststart = folder / "faststart.mp4"
    with av.open(str(clip)) as src, av.open(str(faststart), "w", options={"movflags": "faststart"}) as dst:
        stream = dst.add_stream_from_template(src.streams.video[0])
        for packet in src.demux(src.streams.video[0]):
            if packet.size:
                packet.stream = stream
                dst.mux(packet)
    data = faststart.read_bytes()
    cut = folder / "cut.mp4"
    cut.write_bytes(data[: len(data) * 6 // 10])
    return cut


def write_video(path: Path, frames: int, size: int = 128, seed: int = 0, **mux_options) -> Path:
    """A clip of smooth random colour blobs: a valid H.264 video with no face in it."""
    import av

    rng = np.random.default_rng(seed)
    with av.open(str(path), "w", options=mux_options) as c:
        s = c.add_stream("libx264", rate=25)
        s.width = s.height = size
        s.pix_fmt = "yuv420p"
        base = rng.integers(0, 255, (8, 8, 3)).astype(np.float32)
        for i in range(frames):
            small = np.clip(base + 40 * np.sin(i / 5 + base / 40), 0, 255).astype(np.uint8)
            img = np.kron(small, np.ones((size // 8, size // 8, 1), np.uint8))
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


# ---- a synthetic track of the canonical face (ARKit curves' tests) ----------------------
NAMES = list(BLENDSHAPE_NAMES)
# synthetic_track's frame count, rest frame and frame rate.
FRAMES, NEUTRAL, FPS = 100, 3, 30.0


def ramp(frames: np.ndarray, start: int, hold: int, length: int = 8) -> np.ndarray:
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
    k = np.arange(FRAMES)
    jaw, blink, brow = ramp(k, 30, 15), ramp(k, 80, 4, 3), ramp(k, 50, 10)
    lm = np.repeat(base[None], FRAMES, 0)
    lm[:, 14, 1] -= 0.4 * iod * jaw  # lower lip drops
    lm[:, 159, 1] -= 0.9 * (base[159, 1] - base[145, 1]) * blink  # right upper lid to 10% open
    lm[:, [105, 334], 1] += 0.1 * iod * brow[:, None]
    lm += np.random.default_rng(0).normal(0, 0.002, lm.shape)  # tracker jitter, cm
    lm = one_euro(lm, k / FPS, TrackOptions().landmark_filter(), speed_axis=-1)  # as the tracker filters
    scores = np.zeros((FRAMES, len(NAMES)))
    scores[:, NAMES.index("jawOpen")] = 0.2 + 0.55 * jaw
    scores[:, NAMES.index("eyeBlinkRight")] = 0.1 + 0.6 * blink
    scores[:, NAMES.index("browInnerUp")] = 0.05 + 0.3 * brow
    scores[:, NAMES.index("mouthSmileLeft")] = 0.3 + 0.7 * jaw  # a score with no geometry check
    track = Track(
        times=k / FPS, landmarks_px=np.zeros((FRAMES, N_LANDMARKS, 2), np.float32),
        landmarks_depth=np.zeros((FRAMES, N_LANDMARKS), np.float32),
        landmarks_head=lm.astype(np.float32), presence=np.ones(FRAMES, bool), interpolated=np.zeros(FRAMES, bool),
        held=np.zeros(FRAMES, bool), blendshapes=scores.astype(np.float32), blendshape_names=NAMES,
        head_pose=np.tile(np.eye(4, dtype=np.float32), (FRAMES, 1, 1)), neutral_frame=NEUTRAL, width=64, height=64,
        fps=FPS)
    return track, {"jawOpen": jaw, "eyeBlinkRight": blink, "browInnerUp": brow}


# ---- a track of the rig's own landmarks (retarget tests) -------------------------------
def perfect_track(rig, perf, scale=1.0, angle_deg=0.0, shift=(0.0, 0.0, 0.0), noise=0.0,
                  blendshapes=None, seed=0) -> Track:
    """Landmarks of the CPU-deformed rig, as a tracker would report them (head coordinates
    off by a similarity transform, plus optional noise)."""
    frames = perf.n_frames
    pos, _ = deform(rig, perf.bone_positions, perf.blend_weights)
    lv = rig.landmark_vertices
    lm = np.zeros((frames, len(lv), 3))
    lm[:, lv >= 0] = pos[:, lv[lv >= 0]]
    lm[:, lv < 0] = lm[:, lv >= 0].mean(1, keepdims=True)  # irises: somewhere, unused
    a = np.radians(angle_deg)
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    lm = scale * lm @ rot.T + np.asarray(shift)
    lm += np.random.default_rng(seed).normal(0.0, noise, lm.shape)
    names = list(BLENDSHAPE_NAMES)
    return Track(
        times=perf.times, landmarks_px=np.zeros((frames, len(lv), 2), np.float32),
        landmarks_depth=np.zeros((frames, len(lv)), np.float32),
        landmarks_head=lm.astype(np.float32), presence=np.ones(frames, bool),
        interpolated=np.zeros(frames, bool), held=np.zeros(frames, bool),
        blendshapes=(np.zeros((frames, len(names)), np.float32) if blendshapes is None else blendshapes),
        blendshape_names=names, head_pose=perf.head_pose, neutral_frame=int(np.flatnonzero(perf.key_pose == 0)[0]),
        width=512, height=512, fps=perf.fps,
    )


# ---- a hand-made Animation (export tests) ----------------------------------------------
def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def make_animation(rig, frames=45, fps=30.0, seed=1, t0=0.0) -> Animation:
    """A performance built by hand: bones = rest + small sinusoids (head still), morph
    weights in [0, 1], a head turning (yaw, pitch, roll), random MediaPipe scores and
    (different) random ARKit curves."""
    t = t0 + np.arange(frames) / fps
    B, M = rig.n_bones, rig.n_morphs
    phase = np.arange(B)[None, :, None] * 0.7 + np.arange(3)[None, None, :]
    bones = rig.bone_rest[None] + 0.3 * np.sin(2 * np.pi * 1.3 * t[:, None, None] + phase)
    bones[:, 0] = rig.bone_rest[0]
    weights = 0.5 + 0.5 * np.sin(2 * np.pi * 0.9 * t[:, None] + np.arange(M)[None])
    yaw, pitch, roll = 0.4 * np.sin(2 * np.pi * 0.5 * t), 0.2 * np.sin(2 * np.pi * 0.7 * t), 0.1 * np.cos(t)
    pose = np.tile(np.eye(4), (frames, 1, 1))
    if frames:
        pose[:, :3, :3] = [rot_y(a) @ rot_x(b) @ rot_z(c) for a, b, c in zip(yaw, pitch, roll)]
    pose[:, :3, 3] = [0.5, -1.0, -45.0]
    rng = np.random.default_rng(seed)
    P, R = len(rig.pose_names), len(REGION_NAMES)
    return Animation(
        times=t, fps=fps, bone_names=list(rig.bone_names), bone_positions=bones.astype(np.float32),
        head_pose=pose.astype(np.float32), blend_names=list(rig.morph_names),
        blend_weights=weights.astype(np.float32), pose_names=list(rig.pose_names),
        influences=np.zeros((frames, P, B), np.float32), rest_influence=np.ones((frames, B), np.float32),
        region_names=list(REGION_NAMES), region_influence=np.zeros((frames, R, P), np.float32),
        zone_names=list(ZONE_NAMES), zone_weights=np.zeros((frames, 8), np.float32),
        mediapipe_blendshapes=rng.uniform(0, 1, (frames, len(BLENDSHAPE_NAMES))).astype(np.float32),
        mediapipe_blendshape_names=list(BLENDSHAPE_NAMES), presence=np.ones(frames, bool),
        character=rig.name, arkit_names=list(BLENDSHAPE_NAMES),
        arkit_weights=rng.uniform(0, 1, (frames, len(BLENDSHAPE_NAMES))).astype(np.float32),
    )


# ---- the Khronos glTF validator --------------------------------------------------------
# The npm package ``gltf-validator`` is pinned in tests/tools/package.json; on first use it
# is installed into tests/tools/node_modules (git-ignored) with ``npm install``, so a fresh
# CI machine with node + npm needs nothing else. Tests skip only when npm (or node) is absent.
VALIDATOR_TOOLS = Path(__file__).parent / "tools"
VALIDATOR_SCRIPT = VALIDATOR_TOOLS / "validate_gltf.js"


def ensure_validator() -> None:
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm not installed: cannot run the Khronos glTF validator")
    if (VALIDATOR_TOOLS / "node_modules" / "gltf-validator" / "package.json").is_file():
        return
    proc = subprocess.run(
        ["npm", "install", "--no-audit", "--no-fund", "--prefix", str(VALIDATOR_TOOLS)],
        cwd=VALIDATOR_TOOLS, capture_output=True, text=True, timeout=600, check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"npm install gltf-validator failed:\n{proc.stdout}\n{proc.stderr}")


def validate(path) -> dict:
    """The validator's JSON report for ``path`` (``report['issues']['numErrors']`` etc.)."""
    ensure_validator()
    proc = subprocess.run(["node", str(VALIDATOR_SCRIPT), str(path)], capture_output=True, text=True, timeout=600,
                          check=False)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"glTF validator failed to run on {path}: {proc.stderr}")
    return json.loads(proc.stdout)


def problems(report: dict, max_severity: int = 1) -> list[str]:
    """Messages at or above a severity (0 error, 1 warning, 2 info, 3 hint), one line each."""
    return [f"{m['code']} {m.get('pointer', '')}: {m['message']}"
            for m in report["issues"]["messages"] if m["severity"] <= max_severity]


# ---- the command line in a subprocess, and character files rewritten (character tests) ----
CLI_ENV = dict(os.environ, GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2", PYTHONUNBUFFERED="1")
SAMPLE = REPO / "sample_videos" / "sample.mp4"


def run_cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "capture2face", "-q", *args], capture_output=True, text=True,
                          timeout=timeout, env=CLI_ENV)


def unique(gltf: dict) -> dict:
    """A file no earlier test run prepared (the prepared-character cache is keyed on content)."""
    gltf.setdefault("asset", {})["generator"] = f"capture2face test {uuid.uuid4().hex}"
    return gltf


def rewrite(src: Path, dst: Path, change) -> Path:
    """``src`` with ``change(gltf, binary)`` applied (its JSON as the file has it)."""
    from capture2face.gltf.container import read_gltf_document, write_glb

    gltf, binary = read_gltf_document(src)
    binary = bytearray(binary)
    change(gltf, binary)
    dst.write_bytes(write_glb(unique(gltf), binary))
    return dst

"""Rebuild the real-tool fixtures of tests/test_real_files.py (run from the repository root:
``python tests/data/real_files/make_fixtures.py /path/to/ict-a.glb``; needs node + npm).

``base.glb``: the shared ICT head ict-a.glb simplified by gltfpack to 2 % of its triangles
(every mesh and material kept; ``-noq``: plain floats), nine morphs kept (every mesh keeps
at least one), pruned and its morph targets made sparse by glTF-Transform, its three
textures shrunk to an eighth (so the fixtures stay small). Every other file is one of the
real tools' own outputs from ``base.glb``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))
from capture2face.gltf.container import read_gltf_document, write_glb

GLTFPACK = ["npx", "-y", "gltfpack@1.3.0"]
TRANSFORM = ["npx", "-y", "@gltf-transform/cli@4.5.1"]
# name -> command (IN and OUT replaced)
VARIANTS = {
    "pack-q.glb": [*GLTFPACK, "-i", "IN", "-o", "OUT", "-kn", "-km"],  # KHR_mesh_quantization + texture transform
    "pack-c.glb": [*GLTFPACK, "-i", "IN", "-o", "OUT", "-c"],  # EXT_meshopt_compression
    "pack-cc.glb": [*GLTFPACK, "-i", "IN", "-o", "OUT", "-cc"],
    "pack-khr.glb": [*GLTFPACK, "-i", "IN", "-o", "OUT", "-c", "-ce", "khr"],  # KHR_meshopt_compression
    "pack-vpf.glb": [*GLTFPACK, "-i", "IN", "-o", "OUT", "-vpf", "-vtf", "-vnf", "-c"],
    "pack-vpn-vi.glb": [*GLTFPACK, "-i", "IN", "-o", "OUT", "-vpn", "-vi", "-vp", "16", "-vt", "14"],
    "transform-meshopt.glb": [*TRANSFORM, "meshopt", "IN", "OUT"],
    "transform-quantize.glb": [*TRANSFORM, "quantize", "IN", "OUT"],
    "transform-draco.glb": [*TRANSFORM, "draco", "IN", "OUT"],
    "transform-webp.glb": [*TRANSFORM, "webp", "IN", "OUT"],
    "folder/character.gltf": [*TRANSFORM, "copy", "IN", "OUT"],  # .gltf + .bin + PNGs
}


KEEP_MORPHS = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "browInnerUp", "mouthFunnel",
               "cheekPuff", "PupilDilate_L", "PupilDilate_R")


def keep_morphs(path: Path) -> None:
    """Only the morphs of KEEP_MORPHS (the fixtures stay small; glTF-Transform prunes the rest)."""
    gltf, binary = read_gltf_document(path)
    for mesh in gltf["meshes"]:
        names = mesh.get("extras", {}).get("targetNames")
        if not names:
            continue
        keep = [i for i, n in enumerate(names) if n in KEEP_MORPHS] or [0]
        mesh["extras"]["targetNames"] = [names[i] for i in keep]
        if "weights" in mesh:
            mesh["weights"] = [mesh["weights"][i] for i in keep]
        for prim in mesh["primitives"]:
            prim["targets"] = [prim["targets"][i] for i in keep]
    path.write_bytes(write_glb(gltf, binary))


def shrink_images(path: Path, factor: int = 8) -> None:
    gltf, binary = read_gltf_document(path)
    views = gltf["bufferViews"]
    out = bytearray()
    images = {im["bufferView"]: im for im in gltf.get("images", [])}
    for i, view in enumerate(views):
        data = binary[view.get("byteOffset", 0): view.get("byteOffset", 0) + view["byteLength"]]
        if i in images:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            img = cv2.resize(img, (img.shape[1] // factor, img.shape[0] // factor), interpolation=cv2.INTER_AREA)
            data = cv2.imencode(".png", img)[1].tobytes()
        out.extend(b"\0" * (-len(out) % 4))
        view["byteOffset"], view["byteLength"] = len(out), len(data)
        out.extend(data)
    path.write_bytes(write_glb(gltf, out))


def main(source: str) -> None:
    tmp = HERE / "_tmp.glb"
    subprocess.run([*GLTFPACK, "-i", source, "-o", str(tmp), "-si", "0.02", "-sa", "-noq", "-kn", "-km"], check=True)
    keep_morphs(tmp)
    subprocess.run([*TRANSFORM, "prune", str(tmp), str(tmp)], check=True)
    subprocess.run([*TRANSFORM, "sparse", str(tmp), str(HERE / "base.glb")], check=True)
    tmp.unlink()
    shrink_images(HERE / "base.glb")
    shutil.rmtree(HERE / "folder", ignore_errors=True)
    (HERE / "folder").mkdir()
    for name, cmd in VARIANTS.items():
        cmd = [str(HERE / "base.glb") if c == "IN" else str(HERE / name) if c == "OUT" else c for c in cmd]
        subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main(sys.argv[1])

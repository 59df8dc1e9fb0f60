"""Another ICT-FaceKit identity from two ICT heads: the face opposite one identity about the other.

    python tools/mirror_identity.py ../shared/characters/ict-a.glb ../shared/characters/ict-b.glb \\
        ict-c.glb [--amount 1.0]

ICT-FaceKit is linear: a face is the generic neutral plus identity modes plus expression
shapes, and the expression shapes do not depend on the identity (ict-a and ict-b share every
morph delta to the bit). So ``neutral + amount * (neutral - other)`` is the model's face for
the identity weights ``-amount * w``: with ``amount`` 1 as likely under ICT's N(0, 0.8) prior
as ``other`` itself, and a face no part of this project was tuned on. Only the base POSITION
and NORMAL data change (normals as the same mix, renormalised); morphs, UVs, textures and
the scene stay the first file's. Used for `eval synthetic --actor` on an unseen identity
(docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np
import pygltflib

from capture2face.io.atomic import atomic_path


def _vec3(gltf: pygltflib.GLTF2, blob: bytes | bytearray, accessor: int) -> tuple[int, np.ndarray]:
    """Byte offset and (N, 3) float32 data of a tightly packed VEC3 float accessor."""
    acc = gltf.accessors[accessor]
    view = gltf.bufferViews[acc.bufferView]
    if acc.sparse is not None or view.byteStride not in (None, 12) or acc.componentType != pygltflib.FLOAT:
        raise SystemExit(f"accessor {accessor}: only packed float VEC3 data is handled")
    offset = (view.byteOffset or 0) + (acc.byteOffset or 0)
    return offset, np.frombuffer(blob[offset:offset + acc.count * 12], np.float32).reshape(-1, 3)


def mirror_identity(neutral: Path, other: Path, out: Path, amount: float = 1.0) -> None:
    """Write ``neutral + amount * (neutral - other)`` (base positions and normals) to ``out``."""
    a, b = pygltflib.GLTF2().load(str(neutral)), pygltflib.GLTF2().load(str(other))
    blob, other_blob = bytearray(a.binary_blob()), b.binary_blob()
    if [len(m.primitives) for m in a.meshes] != [len(m.primitives) for m in b.meshes]:
        raise SystemExit("the two heads do not share their meshes")
    for mesh_a, mesh_b in zip(a.meshes, b.meshes):
        for prim_a, prim_b in zip(mesh_a.primitives, mesh_b.primitives):
            for attribute in ("POSITION", "NORMAL"):
                ia, ib = getattr(prim_a.attributes, attribute), getattr(prim_b.attributes, attribute)
                if ia is None or ib is None:
                    continue
                offset, xa = _vec3(a, blob, ia)
                _, xb = _vec3(b, other_blob, ib)
                if xa.shape != xb.shape:
                    raise SystemExit(f"mesh {mesh_a.name}: the two heads differ in vertex count")
                x = xa + amount * (xa - xb)
                if attribute == "NORMAL":
                    x /= np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)
                else:
                    a.accessors[ia].min, a.accessors[ia].max = x.min(0).tolist(), x.max(0).tolist()
                blob[offset:offset + x.nbytes] = x.astype(np.float32).tobytes()
    a.set_binary_blob(bytes(blob))
    try:
        with atomic_path(out) as tmp:  # a failure leaves no partial file beside it
            a.save_binary(str(tmp))
    except OSError as exc:  # the output named, not the temporary file beside it
        raise ValueError(f"cannot write {out}: {exc.strerror or exc}") from None


def check_args(neutral: Path, other: Path, out: Path, amount: float) -> None:
    """Fail before reading anything: a missing head, an output that is a folder, not a .glb,
    or one of the two heads (whatever the spelling: the same file is never overwritten)."""
    for path in (neutral, other):
        if path.is_dir():
            raise ValueError(f"{path}: is a folder, not a .glb")
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
    if out.is_dir():
        raise ValueError(f"{out}: is a folder; give the .glb file to write (e.g. {out / 'ict-c.glb'})")
    if out.suffix.lower() != ".glb":
        raise ValueError(f"{out}: the new head is written as binary glTF; name it {out.with_suffix('.glb').name}")
    for path in (neutral, other):
        if out.exists() and os.path.samefile(out, path) or out.resolve() == path.resolve():
            raise ValueError(f"{out}: is the input {path}; choose another output file")
    if not math.isfinite(amount):
        raise ValueError(f"--amount {amount}: must be a finite number")


def _fail(message: str) -> None:
    print(f"mirror_identity.py: error: {' '.join(message.split())}", file=sys.stderr)
    raise SystemExit(2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("neutral", type=Path, help="the generic neutral head (ict-a.glb)")
    parser.add_argument("other", type=Path, help="another identity of the same model (ict-b.glb)")
    parser.add_argument("out", type=Path, help="the new head (.glb)")
    parser.add_argument("--amount", type=float, default=1.0, help="how far past the neutral (default 1)")
    args = parser.parse_args()
    try:
        check_args(args.neutral, args.other, args.out, args.amount)
    except ValueError as exc:
        _fail(str(exc))
    try:
        mirror_identity(args.neutral, args.other, args.out, args.amount)
    except ValueError as exc:
        _fail(str(exc))
    except (Exception, SystemExit) as exc:  # an unreadable or unmatched pair: one line, not a traceback
        _fail(f"cannot mirror {args.neutral} about {args.other}: {exc}")
    print(args.out)


if __name__ == "__main__":
    main()

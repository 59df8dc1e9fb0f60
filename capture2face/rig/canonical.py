"""MediaPipe's canonical face mesh, read from the ``face_landmarker.task`` model file.

The task file is a zip; its member ``geometry_pipeline_metadata_landmarks.binarypb`` is a
``GeometryPipelineMetadata`` protobuf. No protobuf package is needed: a tiny wire-format
reader pulls out the fields we use.

Top level: field 1 = canonical mesh message, field 2 (repeated) = procrustes landmark basis
(landmark_id varint field 1, weight float field 2). In the mesh: field 3 = vertex buffer
(one float per occurrence, 5 per vertex: x, y, z, u, v), field 4 = triangle indices (one
varint per occurrence). Units cm; +x subject's left, +y up, +z out of the face; UV origin
top-left.
"""

from __future__ import annotations

import os
import struct
import zipfile
from dataclasses import dataclass

import numpy as np

from capture2face.errors import CaptureError
from capture2face.models.face_model import find_face_model
from capture2face.topology import N_MESH

MEMBER = "geometry_pipeline_metadata_landmarks.binarypb"


@dataclass
class CanonicalMesh:
    """The canonical face.

    Attributes:
        vertices: (468, 3) float32 positions, cm.
        uvs: (468, 2) float32, origin top-left.
        triangles: (898, 3) int32, counter-clockwise seen from the front (+z).
        procrustes_ids: (N,) int32 landmark ids of the procrustes basis.
        procrustes_weights: (N,) float32 their weights.
    """

    vertices: np.ndarray
    uvs: np.ndarray
    triangles: np.ndarray
    procrustes_ids: np.ndarray
    procrustes_weights: np.ndarray


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7


def _fields(buf: bytes):
    """Yield (field number, wire type, value) for each field of a message.

    Length-delimited fields yield raw bytes; 32-bit fields yield the float; varints the int.
    """
    pos = 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == 1:
            value = struct.unpack_from("<d", buf, pos)[0]
            pos += 8
        elif wire == 2:
            length, pos = _varint(buf, pos)
            value = buf[pos:pos + length]
            pos += length
        elif wire == 5:
            value = struct.unpack_from("<f", buf, pos)[0]
            pos += 4
        else:
            raise ValueError(f"unsupported wire type {wire}")
        yield number, wire, value


def _packed_or_single(wire: int, value, kind: str) -> list:
    """A repeated scalar may be packed (wire 2) or one per occurrence."""
    if wire != 2:
        return [value]
    if kind == "f":
        return list(np.frombuffer(value, "<f4"))
    out, pos = [], 0
    while pos < len(value):
        v, pos = _varint(value, pos)
        out.append(v)
    return out


def parse_geometry_metadata(data: bytes) -> CanonicalMesh:
    """Decode the ``GeometryPipelineMetadata`` protobuf bytes."""
    floats: list[float] = []
    indices: list[int] = []
    ids: list[int] = []
    weights: list[float] = []
    for number, wire, value in _fields(data):
        if number == 1 and wire == 2:
            for n2, w2, v2 in _fields(value):
                if n2 == 3:
                    floats += _packed_or_single(w2, v2, "f")
                elif n2 == 4:
                    indices += _packed_or_single(w2, v2, "i")
        elif number == 2 and wire == 2:
            lid, weight = 0, 0.0
            for n2, _w2, v2 in _fields(value):
                if n2 == 1:
                    lid = int(v2)
                elif n2 == 2:
                    weight = float(v2)
            ids.append(lid)
            weights.append(weight)
    buf = np.asarray(floats, np.float32).reshape(-1, 5)
    return CanonicalMesh(
        vertices=np.ascontiguousarray(buf[:, :3]),
        uvs=np.ascontiguousarray(buf[:, 3:]),
        triangles=np.asarray(indices, np.int32).reshape(-1, 3),
        procrustes_ids=np.asarray(ids, np.int32),
        procrustes_weights=np.asarray(weights, np.float32),
    )


def load_canonical_mesh(model_path: str | os.PathLike | None = None) -> CanonicalMesh:
    """Read the canonical mesh from ``face_landmarker.task`` (resolved by ``find_face_model``)."""
    path = find_face_model(model_path)
    try:
        with zipfile.ZipFile(path) as zf:
            data = zf.read(MEMBER)
    except (zipfile.BadZipFile, KeyError, OSError) as exc:
        raise CaptureError(f"{path}: not a face_landmarker.task with a canonical mesh "
                           f"({exc.__class__.__name__})") from None
    mesh = parse_geometry_metadata(data)
    if mesh.vertices.shape[0] != N_MESH or mesh.triangles.size == 0:
        raise CaptureError(f"{path}: unexpected canonical mesh ({mesh.vertices.shape[0]} vertices)")
    return mesh

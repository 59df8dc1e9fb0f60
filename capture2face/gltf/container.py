"""The glTF 2.0 container (.glb, .gltf): a writer and a reader, on pygltflib.

pygltflib parses and writes the document and its chunks (GLB header, JSON, BIN; data
URIs); the document is handled here as plain JSON-like dicts, and accessors are decoded
(and encoded) with NumPy: sparse, ``byteStride``, normalized and quantized integers.
What a FaceRig or an animation puts into a .glb is in :mod:`capture2face.gltf.rig_export`
and :mod:`capture2face.gltf.animation_export`.

Writer rules that keep the Khronos validator quiet: every buffer view starts on a 4-byte
boundary (so every accessor is aligned to its component size), vertex attributes are
tightly packed (no ``byteStride``), POSITION and animation-input accessors carry min/max,
and images are stored as PNG inside buffer views.
"""

from __future__ import annotations

import base64
import json
import os
import struct
import urllib.parse
import warnings
from typing import Any

import cv2
import numpy as np
import pygltflib

from capture2face.errors import CaptureError

# Units and the conventions of our own files (capture2face.gltf.rig_export).
METRES_PER_CM = 0.01
CM_PER_METRE = 100.0
EXTRAS_KEY = "capture2face"
EXTRAS_FORMAT = "capture2face.FaceRig.glb/1"
ROOT_NODE_NAME = "capture2face_root"
EYE_JOINT_NAMES = ("eye_R", "eye_L")  # the subject's right eye first, as FaceRig.eye_centres
SAMPLER_LINEAR_CLAMP = {"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}

GLB_MAGIC = 0x46546C67  # "glTF"
#: Character files the glTF reader takes: a .vrm (VRM 0.x / 1.0) is a .glb with its own extensions.
CHARACTER_SUFFIXES = (".glb", ".gltf", ".vrm")

ARRAY_BUFFER = 34962
ELEMENT_ARRAY_BUFFER = 34963

# componentType codes <-> NumPy dtypes (little-endian, as glTF requires).
COMPONENT_DTYPES = {
    5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"),
    5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4"),
}
DTYPE_COMPONENTS = {v: k for k, v in COMPONENT_DTYPES.items()}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
SIZE_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}


def encode_png(image: np.ndarray) -> bytes:
    """(H, W, C) uint8 RGB/RGBA or (H, W) grey -> PNG bytes (lossless)."""
    image = np.ascontiguousarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA)
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise CaptureError("could not encode a texture as PNG")
    return buf.tobytes()


KTX2_MAGIC = b"\xabKTX 20\xbb\r\n\x1a\n"


def decode_image(data: bytes) -> np.ndarray:
    """PNG/JPEG/WebP/KTX2 bytes -> (H, W, C) uint8 RGB or RGBA (grey images become RGB).

    KTX2 (``KHR_texture_basisu``: ETC1S or UASTC Basis, the way gltfpack ``-tc`` and
    glTF-Transform ``etc1s``/``uastc`` write it) is transcoded with the ``alktx2``
    package (Basis Universal) when it is installed."""
    data = bytes(data)
    if not data:
        raise ValueError("no bytes")  # OpenCV asserts on an empty buffer
    if data[:12] == KTX2_MAGIC:
        data = _ktx2_png(data)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None:
        raise ValueError("undecodable image")
    if image.dtype != np.uint8:  # 16-bit PNGs
        image = (image.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _ktx2_png(data: bytes) -> bytes:
    """A KTX2 texture's first level transcoded to PNG bytes (RGBA)."""
    try:
        import alktx2
    except ImportError:
        raise ValueError("a KTX2 texture needs the alktx2 package (pip install alktx2)") from None
    try:
        png, _ = alktx2.decode_ktx2_to_bytes(data, format="png")
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"KTX2 texture not transcodable: {exc}") from None
    return png


class GlbBuilder:
    """Accumulates the glTF JSON and its one binary buffer; :meth:`to_bytes` makes the .glb."""

    def __init__(self, generator: str = "capture2face"):
        self.gltf: dict[str, Any] = {"asset": {"version": "2.0", "generator": generator}}
        self.bin = bytearray()

    def _list(self, key: str) -> list:
        return self.gltf.setdefault(key, [])

    def add(self, key: str, obj: dict) -> int:
        """Append ``obj`` to the top-level array ``key``; return its index."""
        items = self._list(key)
        items.append(obj)
        return len(items) - 1

    def buffer_view(self, data: bytes, target: int | None = None) -> int:
        """Append raw bytes on a 4-byte boundary as a new buffer view."""
        self.bin.extend(b"\0" * (-len(self.bin) % 4))
        view = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.bin.extend(data)
        return self.add("bufferViews", view)

    def accessor(
        self, array: np.ndarray, target: int | None = None, minmax: bool = False,
        normalized: bool = False, gltf_type: str | None = None,
    ) -> int:
        """Store ``array`` ((N,) or (N, k), a glTF component dtype) as one accessor.

        Args:
            target: ARRAY_BUFFER for vertex attributes, ELEMENT_ARRAY_BUFFER for indices,
                None for animation data and inverse bind matrices.
            minmax: write per-component ``min``/``max`` (required for POSITION and for
                animation sampler inputs).
        """
        array = np.ascontiguousarray(array)
        dtype = array.dtype.newbyteorder("<") if array.dtype.byteorder == ">" else array.dtype
        if dtype not in DTYPE_COMPONENTS:
            raise TypeError(f"no glTF component type for {array.dtype}")
        width = 1 if array.ndim == 1 else int(np.prod(array.shape[1:]))
        flat = array.reshape(len(array), width).astype(dtype, copy=False)
        acc: dict[str, Any] = {
            "bufferView": self.buffer_view(flat.tobytes(), target),
            "componentType": DTYPE_COMPONENTS[dtype],
            "count": int(len(array)),
            "type": gltf_type or SIZE_TYPES[width],
        }
        if normalized:
            acc["normalized"] = True
        if minmax and len(array):
            cast = float if dtype.kind == "f" else int
            acc["min"] = [cast(v) for v in flat.min(axis=0)]
            acc["max"] = [cast(v) for v in flat.max(axis=0)]
        return self.add("accessors", acc)

    def image_png(self, image: np.ndarray, name: str) -> int:
        view = self.buffer_view(encode_png(image))
        return self.add("images", {"bufferView": view, "mimeType": "image/png", "name": name})

    def to_bytes(self) -> bytes:
        """The complete .glb (pygltflib writes the header and the padded chunks)."""
        self.bin.extend(b"\0" * (-len(self.bin) % 4))
        if self.bin:
            self.gltf["buffers"] = [{"byteLength": len(self.bin)}]
        _check_finite(self.gltf)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # dataclasses_json's notes on optional fields
            doc = pygltflib.GLTF2.from_dict(self.gltf)
        doc.set_binary_blob(bytes(self.bin))
        return b"".join(doc.save_to_bytes())


def _check_finite(value) -> None:
    """JSON has no NaN or infinity: refuse them here rather than write an invalid file."""
    json.dumps(value, allow_nan=False)


def _plain(value):
    """pygltflib's dicts -> the file's JSON: unset (None) properties dropped; extras and
    extensions kept as they are."""
    if isinstance(value, dict):
        return {k: (v if k in ("extras", "extensions") else _plain(v)) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


# Required extensions the reader honours: quantized attributes are read like any other
# accessor (the node's transform dequantizes them); meshopt and Draco streams are decoded
# with their packages; KTX2 and WebP images are decoded (a texture that still cannot be
# read is the texture code's concern, not the file's); material extensions only change
# the shading, which the renderer does its own way.
MESHOPT_EXTENSIONS = ("EXT_meshopt_compression", "KHR_meshopt_compression")
DRACO = "KHR_draco_mesh_compression"
SUPPORTED_REQUIRED = ("KHR_mesh_quantization", *MESHOPT_EXTENSIONS, DRACO, "EXT_texture_webp",
                      "KHR_texture_basisu", "KHR_texture_transform")
SHADING_ONLY_PREFIX = "KHR_materials_"
MESHOPT = MESHOPT_EXTENSIONS[0]
# Image sources a texture may name in an extension, tried before its plain ``source``.
TEXTURE_SOURCE_EXTENSIONS = ("EXT_texture_webp", "KHR_texture_basisu")


def check_required_extensions(gltf: dict, path: str) -> None:
    """A file that requires an extension this reader cannot honour fails here, in one
    line naming it (instead of a confusing error about its buffers later).

    Read: ``KHR_mesh_quantization`` (integer attributes, dequantized by the node's
    transform), ``EXT_meshopt_compression`` / ``KHR_meshopt_compression`` (with the
    ``meshoptimizer`` package), ``KHR_draco_mesh_compression`` (with ``DracoPy``),
    ``EXT_texture_webp`` (OpenCV), ``KHR_texture_basisu`` (``alktx2``),
    ``KHR_texture_transform``, ``KHR_materials_*`` (shading only).
    """
    required = [str(e) for e in gltf.get("extensionsRequired") or []]
    missing = [e for e in required if e not in SUPPORTED_REQUIRED and not e.startswith(SHADING_ONLY_PREFIX)]
    if missing:
        raise CaptureError(f"{path}: requires the glTF extension{'s' if len(missing) > 1 else ''} "
                           f"{', '.join(missing)}, which capture2face cannot read")
    for ext in required:
        if ext in MESHOPT_EXTENSIONS:
            _meshoptimizer(path, ext)
        elif ext == DRACO:
            _dracopy(path)


def _meshoptimizer(path: str, ext: str = MESHOPT):
    try:
        import meshoptimizer
    except ImportError:
        raise CaptureError(f"{path}: requires the glTF extension {ext}, which needs the meshoptimizer "
                           "package (pip install meshoptimizer; it builds from source with a C++ compiler)") from None
    return meshoptimizer


def _dracopy(path: str):
    try:
        import DracoPy
    except ImportError:
        raise CaptureError(f"{path}: requires the glTF extension {DRACO}, which needs the DracoPy package "
                           "(pip install DracoPy), or export it again without Draco compression") from None
    return DracoPy


def _meshopt_decode(path: str, ext: dict, data: bytes, name: str = MESHOPT) -> bytes:
    """The bytes of a meshopt-compressed buffer view: the compressed stream decoded
    (ATTRIBUTES, TRIANGLES, INDICES), then its filter undone. A stream that does not
    decode (corrupt, or a codec version newer than the installed meshoptimizer) fails
    in one line."""
    mo = _meshoptimizer(path, name)
    count, stride = int(ext["count"]), int(ext["byteStride"])
    mode, filt = ext.get("mode", "ATTRIBUTES"), ext.get("filter", "NONE")
    try:
        if mode == "ATTRIBUTES":
            out = mo.decode_vertex_buffer(count, stride, data, dtype=np.dtype((np.void, stride))).view(np.uint8)
        elif mode in ("TRIANGLES", "INDICES"):
            decode = mo.decode_index_buffer if mode == "TRIANGLES" else mo.decode_index_sequence
            # The wrapper decodes into a uint32 array whatever the index size: its first
            # count * stride bytes are the indices, in the file's own width.
            out = np.asarray(decode(count, stride, data)).view(np.uint8)[: count * stride]
        else:
            raise CaptureError(f"{path}: {name} mode '{mode}' is unknown")
    except (RuntimeError, ValueError) as exc:
        raise CaptureError(f"{path}: a {name} buffer view does not decode ({exc}); the file is corrupt or "
                           "newer than the installed meshoptimizer package") from None
    if filt != "NONE":
        undo = {"OCTAHEDRAL": mo.decode_filter_oct, "QUATERNION": mo.decode_filter_quat,
                "EXPONENTIAL": mo.decode_filter_exp}.get(filt)
        if undo is None:
            raise CaptureError(f"{path}: {name} filter '{filt}' is unknown")
        out = np.asarray(undo(np.ascontiguousarray(out), count, stride)).view(np.uint8)
    return out.tobytes()


class GlbReader:
    """Parses a .glb (or a .gltf whose buffers are embedded as data URIs) and reads accessors."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        if not os.path.isfile(self.path):
            raise CaptureError(f"{self.path}: no such file")
        with open(self.path, "rb") as fh:
            data = fh.read()
        try:
            self.gltf, self.bin = self._parse(data)
        except (ValueError, KeyError, struct.error, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CaptureError(f"{self.path}: not a readable glTF binary (.glb) file ({exc})") from None
        version = str(self.gltf.get("asset", {}).get("version", ""))
        if not version.startswith("2."):
            raise CaptureError(f"{self.path}: glTF version {version or '?'} is not supported (need 2.0)")
        check_required_extensions(self.gltf, self.path)
        self._cache: dict[int, np.ndarray] = {}
        self._decoded: dict[int, bytes] = {}
        self._draco = _draco_accessors(self.gltf)
        self._draco_meshes: dict[int, Any] = {}

    @staticmethod
    def _parse(data: bytes) -> tuple[dict, bytes]:
        """(document as dicts, BIN chunk). The GLB header is checked first (pygltflib
        reads a truncated file without a word)."""
        if data[:1] != b"{":
            if len(data) < 12:
                raise ValueError("file too short")
            magic, version, length = struct.unpack_from("<III", data, 0)
            if magic != GLB_MAGIC:
                raise ValueError("no glTF magic")
            if version != 2:
                raise ValueError(f"GLB container version {version}")
            if length > len(data):
                raise ValueError(f"truncated: header says {length} bytes, file has {len(data)}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # dataclasses_json's notes on optional fields
            try:
                doc = (pygltflib.GLTF2.from_json(data.decode("utf-8")) if data[:1] == b"{"
                       else pygltflib.GLTF2.load_from_bytes(data))
            except (ValueError, KeyError, TypeError, AttributeError, struct.error, UnicodeDecodeError) as exc:
                # pygltflib's parser meets a malformed document with whatever it trips on.
                raise ValueError(f"{exc.__class__.__name__}: {exc}") from None
        if doc is None:
            raise ValueError("no JSON chunk")
        return _plain(json.loads(doc.to_json())), bytes(doc.binary_blob() or b"")

    # ---- raw data -----------------------------------------------------------------------
    def _buffer(self, index: int) -> bytes:
        buf = self.gltf["buffers"][index]
        uri = buf.get("uri")
        if uri is None:
            return self.bin
        return self._uri_bytes(uri)

    def _uri_bytes(self, uri: str) -> bytes:
        """Bytes behind a glTF URI: a base64 data URI or a file beside the .gltf."""
        return uri_bytes(uri, os.path.dirname(self.path), self.path)

    def view_bytes(self, index: int) -> tuple[bytes, int | None]:
        view = self.gltf["bufferViews"][index]
        exts = view.get("extensions") or {}
        name = next((e for e in MESHOPT_EXTENSIONS if e in exts), None)
        if name is not None:
            ext = exts[name]
            if index not in self._decoded:  # decompressed once per view
                raw = self._slice(self._buffer(ext["buffer"]), ext.get("byteOffset", 0), ext["byteLength"], index,
                                  ext["buffer"])
                self._decoded[index] = _meshopt_decode(self.path, ext, raw, name)
            return self._decoded[index], ext.get("byteStride")
        return self._slice(self._buffer(view.get("buffer", 0)), view.get("byteOffset", 0), view["byteLength"],
                           index, view.get("buffer", 0)), view.get("byteStride")

    def _slice(self, buf: bytes, start: int, length: int, index: int, buffer: int = 0) -> bytes:
        end = start + length
        if end > len(buf):
            uri = self.gltf["buffers"][buffer].get("uri", "")
            named = f" ('{uri}', {len(buf)} bytes)" if uri and not uri.startswith("data:") else ""
            raise CaptureError(f"{self.path}: buffer view {index} runs past the end of buffer {buffer}{named}, "
                               f"at byte {end}: the buffer is cut short or not the one this file was written with")
        return buf[start:end]

    def _read_dense(self, view_index: int, offset: int, count: int, dtype: np.dtype, width: int) -> np.ndarray:
        data, stride = self.view_bytes(view_index)
        elem = dtype.itemsize * width
        stride = stride or elem
        if count and offset + stride * (count - 1) + elem > len(data):
            raise CaptureError(f"{self.path}: an accessor runs past the end of its buffer view")
        raw = np.frombuffer(data, np.uint8, count=stride * (count - 1) + elem if count else 0, offset=offset)
        if stride == elem:
            return raw.view(dtype).reshape(count, width).copy()
        rows = np.lib.stride_tricks.as_strided(raw, shape=(count, elem), strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def accessor(self, index: int, as_float: bool = True) -> np.ndarray:
        """(count, k) array of accessor ``index`` (k = 1 for SCALAR), sparse and
        ``byteStride`` resolved; normalized integers become floats in [0, 1] / [-1, 1]
        when ``as_float``."""
        key = index * 2 + int(as_float)
        if key in self._cache:
            return self._cache[key]
        try:
            acc = self.gltf["accessors"][index]
            dtype = COMPONENT_DTYPES[acc["componentType"]]
            width = TYPE_SIZES[acc["type"]]
        except (IndexError, KeyError, TypeError):
            raise CaptureError(f"{self.path}: accessor {index} is missing or malformed") from None
        count = int(acc["count"])
        if index in self._draco:
            out = self._draco_values(index, count, dtype, width)
        elif "bufferView" in acc:
            out = self._read_dense(acc["bufferView"], acc.get("byteOffset", 0), count, dtype, width)
        else:
            out = np.zeros((count, width), dtype)
        sparse = acc.get("sparse")
        if sparse:
            n = int(sparse["count"])
            idx_spec, val_spec = sparse["indices"], sparse["values"]
            idx = self._read_dense(idx_spec["bufferView"], idx_spec.get("byteOffset", 0), n,
                                   COMPONENT_DTYPES[idx_spec["componentType"]], 1)[:, 0]
            vals = self._read_dense(val_spec["bufferView"], val_spec.get("byteOffset", 0), n, dtype, width)
            out = out.copy()
            out[idx.astype(np.int64)] = vals
        if as_float and acc.get("normalized") and dtype.kind in "iu":
            scale = float(np.iinfo(dtype).max)
            out = np.maximum(out.astype(np.float32) / scale, -1.0)
        if out.dtype.kind == "f" and not np.isfinite(out).all():
            # A corrupt or mis-decoded stream: refuse it rather than draw garbage.
            raise CaptureError(f"{self.path}: accessor {index} holds non-finite values (a corrupt file)")
        self._cache[key] = out
        return out

    def _draco_values(self, index: int, count: int, dtype: np.dtype, width: int) -> np.ndarray:
        """Accessor ``index`` of a ``KHR_draco_mesh_compression`` primitive: its attribute
        (or the triangle list) from the decoded Draco mesh, decoded once per view."""
        view, uid = self._draco[index]
        if view not in self._draco_meshes:
            raw, _ = self.view_bytes(view)
            draco = _dracopy(self.path)
            try:
                self._draco_meshes[view] = draco.decode(raw)
            except (draco.FileTypeException, ValueError, RuntimeError) as exc:
                raise CaptureError(f"{self.path}: a {DRACO} stream does not decode ({exc})") from None
        mesh = self._draco_meshes[view]
        if uid is None:
            values = np.asarray(mesh.faces).reshape(-1, 1)
        else:
            attr = mesh.get_attribute_by_unique_id(uid)
            if attr is None:
                raise CaptureError(f"{self.path}: {DRACO} attribute {uid} is missing from its stream")
            values = np.asarray(attr["data"]).reshape(len(attr["data"]), -1)
        if values.shape != (count, width):
            raise CaptureError(f"{self.path}: {DRACO} decoded {values.shape[0]} x {values.shape[1]} values for "
                               f"accessor {index} ({count} x {width})")
        return values.astype(dtype)

    def image(self, index: int) -> np.ndarray:
        """(H, W, C) uint8 RGB(A) of image ``index`` (embedded, data URI or file beside the glTF)."""
        img = self.gltf["images"][index]
        try:
            if "bufferView" in img:
                data, _ = self.view_bytes(img["bufferView"])
            else:
                data = self._uri_bytes(img["uri"])
            return decode_image(data)
        except (OSError, ValueError, KeyError) as exc:
            uri = img.get("uri", "") if isinstance(img.get("uri"), str) else ""
            named = f" ('{uri}')" if uri and not uri.startswith("data:") else ""  # the file to look at
            raise CaptureError(f"{self.path}: image {index}{named} is unreadable "
                               f"({exc.__class__.__name__}: {exc})") from None

    def texture_sources(self, texture_info: dict | None) -> list[int]:
        """The images a textureInfo may sample, best first: those ``EXT_texture_webp`` /
        ``KHR_texture_basisu`` name, then the plain ``source`` (their fallback)."""
        if not texture_info:
            return []
        tex = self.gltf.get("textures", [])[texture_info["index"]]
        exts = tex.get("extensions") or {}
        sources = [int(exts[e]["source"]) for e in TEXTURE_SOURCE_EXTENSIONS if "source" in (exts.get(e) or {})]
        return sources + ([int(tex["source"])] if tex.get("source") is not None else [])

    def texture_image(self, texture_info: dict | None) -> np.ndarray | None:
        """The image behind a material's textureInfo, or None."""
        if not texture_info:
            return None
        sources = self.texture_sources(texture_info)
        for k, source in enumerate(sources):
            try:
                return self.image(source)
            except CaptureError:
                if k == len(sources) - 1:
                    raise
        return None


def _draco_accessors(gltf: dict) -> dict[int, tuple[int, int | None]]:
    """accessor -> (Draco buffer view, attribute unique id; None for the indices) for
    every primitive compressed with ``KHR_draco_mesh_compression``."""
    out: dict[int, tuple[int, int | None]] = {}
    for mesh in gltf.get("meshes", []):
        for prim in mesh.get("primitives", []):
            ext = (prim.get("extensions") or {}).get(DRACO)
            if not ext:
                continue
            view = int(ext["bufferView"])
            for semantic, uid in (ext.get("attributes") or {}).items():
                if semantic in prim.get("attributes", {}):
                    out[int(prim["attributes"][semantic])] = (view, int(uid))
            if "indices" in prim:
                out[int(prim["indices"])] = (view, None)
    return out


def texture_transform(texture_info: dict | None) -> tuple[int, np.ndarray]:
    """The texture coordinate set a textureInfo samples and its ``KHR_texture_transform``
    as a (2, 3) matrix (uv' = M @ (u, v, 1)); the identity when it has none.

    glTF's order: translation * rotation * scale, the rotation matrix as the extension's
    GLSL writes it (column-major: columns (cos, sin), (-sin, cos)); the extension's
    ``texCoord`` overrides the textureInfo's."""
    info = texture_info or {}
    ext = (info.get("extensions") or {}).get("KHR_texture_transform") or {}
    tex_coord = int(ext.get("texCoord", info.get("texCoord", 0)))
    ox, oy = (float(v) for v in ext.get("offset", (0.0, 0.0)))
    sx, sy = (float(v) for v in ext.get("scale", (1.0, 1.0)))
    c, s = np.cos(float(ext.get("rotation", 0.0))), np.sin(float(ext.get("rotation", 0.0)))
    return tex_coord, np.array([[c * sx, -s * sy, ox], [s * sx, c * sy, oy]])


# ---- a file kept as it is: raw JSON and chunks, every resource embedded ---------------------
_MIME_BY_SUFFIX = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp",
                   ".ktx2": "image/ktx2"}


def read_gltf_document(path: str | os.PathLike) -> tuple[dict, bytes]:
    """(JSON document exactly as the file has it, GLB BIN chunk or b"") of a .glb or .gltf,
    without a parser's defaults or rewrites (pygltflib merges and moves buffers)."""
    path = os.fspath(path)
    with open(path, "rb") as fh:
        data = fh.read()
    try:
        if data[:1] == b"{":
            return json.loads(data.decode("utf-8")), b""
        magic, version, length = struct.unpack_from("<III", data, 0)
        if magic != GLB_MAGIC or version != 2 or length > len(data):
            raise ValueError("not a glTF 2 binary")
        pos, doc, binary = 12, None, b""
        while pos + 8 <= length:
            size, kind = struct.unpack_from("<II", data, pos)
            chunk = data[pos + 8: pos + 8 + size]
            if kind == 0x4E4F534A:  # JSON
                doc = json.loads(chunk.decode("utf-8"))
            elif kind == 0x004E4942 and not binary:  # BIN
                binary = bytes(chunk)
            pos += 8 + size + (-size % 4)
        if doc is None:
            raise ValueError("no JSON chunk")
        return doc, binary
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: not a readable glTF file ({exc})") from None


def uri_bytes(uri: str, base_dir: str, path: str = "") -> bytes:
    """Bytes behind a glTF URI: a base64 data URI or a (percent-encoded) file beside the .gltf."""
    if uri.startswith("data:"):
        return base64.b64decode(uri.split(",", 1)[1])
    file = os.path.join(base_dir, urllib.parse.unquote(uri))
    try:
        with open(file, "rb") as fh:
            return fh.read()
    except OSError:
        where = "the .gltf" if str(path).lower().endswith(".gltf") else "the file"
        raise CaptureError(f"{path or base_dir}: '{uri}' is missing (it must lie beside {where})") from None


def _image_bytes(uri: str, base_dir: str, path: str) -> bytes | None:
    """An image's bytes, or None where they cannot be read (a file missing beside the
    .gltf, a broken data URI): the import said so and drew the material's base colour; the
    export stores one white texel there, which shows the same base colour factor."""
    try:
        return uri_bytes(uri, base_dir, path)
    except (CaptureError, ValueError):
        return None


def embed_resources(gltf: dict, binary: bytes, base_dir: str, path: str = "") -> bytearray:
    """Make ``gltf`` self-contained: every buffer with a URI (a .gltf's .bin, data URIs)
    appended to the one GLB buffer (buffer views and meshopt streams re-pointed), every
    image with a URI stored in a buffer view (one white texel for an image whose file is
    missing: its material shows its base colour factor, as the import drew it). Buffers
    with no data and no URI (meshopt fallbacks) stay. Returns the new BIN chunk; ``gltf``
    is changed in place."""
    out = bytearray(binary)
    buffers = gltf.get("buffers", [])
    glb_owner = 0 if binary and buffers and "uri" not in buffers[0] else None
    place: dict[int, tuple[int, int]] = {}  # old buffer -> (new buffer, added offset)
    kept = [{"byteLength": 0}]
    for i, buf in enumerate(buffers):
        if i == glb_owner:
            place[i] = (0, 0)
        elif "uri" in buf:
            out.extend(b"\0" * (-len(out) % 16))
            place[i] = (0, len(out))
            out.extend(uri_bytes(buf["uri"], base_dir, path)[: int(buf["byteLength"])])
        else:
            place[i] = (len(kept), 0)
            kept.append(buf)
    for view in gltf.get("bufferViews", []):
        for holder in [view] + [e for k, e in (view.get("extensions") or {}).items() if k in MESHOPT_EXTENSIONS]:
            new, shift = place[int(holder.get("buffer", 0))]
            holder["buffer"], holder["byteOffset"] = new, int(holder.get("byteOffset", 0)) + shift
    for image in gltf.get("images", []):
        if "uri" in image:
            uri = image.pop("uri")
            data = _image_bytes(uri, base_dir, path)
            mime = uri[5:].split(";", 1)[0] if uri.startswith("data:") else \
                _MIME_BY_SUFFIX.get(os.path.splitext(urllib.parse.unquote(uri))[1].lower(), "image/png")
            if data is None:
                data, mime = encode_png(np.full((1, 1, 3), 255, np.uint8)), "image/png"
                image["mimeType"] = mime
            out.extend(b"\0" * (-len(out) % 4))
            gltf.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(out), "byteLength": len(data)})
            out.extend(data)
            image["bufferView"], image["mimeType"] = len(gltf["bufferViews"]) - 1, image.get("mimeType", mime)
    kept[0]["byteLength"] = len(out)
    gltf["buffers"] = kept
    return out


def write_glb(gltf: dict, binary: bytes | bytearray) -> bytes:
    """The .glb of a JSON document and its BIN chunk (both padded to 4 bytes)."""
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    if gltf.get("buffers"):
        gltf["buffers"][0]["byteLength"] = len(binary)
    _check_finite(gltf)
    text = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", GLB_MAGIC, 2, 12 + len(chunks)) + chunks

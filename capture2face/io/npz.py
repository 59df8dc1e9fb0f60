"""Lossless save/load of the stage dataclasses (``Track``, ``FaceRig``, ``Animation``) as .npz.

Every field is stored under its own name: arrays as they are (dtype and shape kept, so a
round trip is bit-exact), lists of strings as unicode arrays, scalars as 0-d arrays.
No pickle is used, so loading a file from someone else is safe.
"""

from __future__ import annotations

import dataclasses
import os
import typing
import zipfile
from typing import Any, TypeVar

import numpy as np

from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path

T = TypeVar("T")

FORMAT_KEY = "__format__"


def save_dataclass(obj: Any, path: str | os.PathLike, format_name: str, compress: bool = True) -> None:
    """Write ``obj``'s fields to ``path`` (.npz) atomically."""
    arrays: dict[str, np.ndarray] = {FORMAT_KEY: np.array(format_name)}
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        if value is None:
            continue
        if isinstance(value, (list, tuple)):
            value = np.array(list(value), dtype=str) if len(value) else np.zeros(0, dtype="<U1")
        # Disk-backed arrays (FrameArray: a long clip's landmarks) stream chunk by chunk.
        arrays[field.name] = value if hasattr(value, "iter_chunks") else np.asarray(value)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        _write_npz(fh, arrays, compress)


def _write_npz(fh, arrays: dict, compress: bool) -> None:
    """What ``np.savez[_compressed]`` writes, but arrays with ``iter_chunks()`` (and
    ``shape``, ``dtype``) are written a chunk at a time instead of read whole."""
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(fh, "w", compression=mode, allowZip64=True) as zf:
        for name, value in arrays.items():
            with zf.open(name + ".npy", "w", force_zip64=True) as out:
                if isinstance(value, np.ndarray):
                    np.lib.format.write_array(out, value, allow_pickle=False)
                    continue
                header = {"descr": np.lib.format.dtype_to_descr(np.dtype(value.dtype)),
                          "fortran_order": False, "shape": tuple(value.shape)}
                np.lib.format.write_array_header_1_0(out, header)
                for chunk in value.iter_chunks(1 << 20):  # small blocks: zlib streams them
                    out.write(memoryview(np.ascontiguousarray(chunk, value.dtype)).cast("B"))


def load_dataclass(cls: type[T], path: str | os.PathLike, format_name: str) -> T:
    """Read a file written by :func:`save_dataclass` back into ``cls``.

    Raises :class:`CaptureError` with a one-line message when the file is missing,
    corrupt or of another kind.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise CaptureError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as data:
            stored = {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise CaptureError(f"{path}: not a readable {format_name} file ({exc.__class__.__name__})") from None
    if stored.get(FORMAT_KEY, np.array("")).item() != format_name:
        raise CaptureError(f"{path}: not a {format_name} file")
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for field in dataclasses.fields(cls):
        if field.name not in stored:
            if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
                raise CaptureError(f"{path}: {format_name} file lacks '{field.name}'")
            continue
        value = stored[field.name]
        hint = str(hints.get(field.name, ""))
        if hint.startswith("list[str]"):
            value = [str(s) for s in value.tolist()]
        elif hint in ("<class 'int'>", "int"):
            value = int(value)
        elif hint in ("<class 'float'>", "float"):
            value = float(value)
        elif hint in ("<class 'str'>", "str"):
            value = str(value)
        elif hint in ("<class 'bool'>", "bool"):
            value = bool(value)
        kwargs[field.name] = value
    return cls(**kwargs)

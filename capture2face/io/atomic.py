"""Atomic output: write to a temporary name beside the target, then rename.

An interrupted run (crash, SIGINT, SIGTERM) therefore never leaves a half-written file
under the final name; at worst a ``.tmp-*`` file that the next run overwrites or removes.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from capture2face.io.paths import ERRORS as PATH_ERRORS

# mkstemp creates files readable by the owner only; outputs get the usual permissions.
_UMASK = os.umask(0)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK
DIR_MODE = 0o777 & ~_UMASK


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    ``suffix`` defaults to the target's own suffix so that libraries that pick a format
    from the file name (PyAV, OpenCV, NumPy) still do the right thing.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(
            prefix=f".tmp-{path.stem}-", suffix=path.suffix if suffix is None else suffix, dir=path.parent
        )
    except OSError as exc:  # "out.json: Permission denied", not the temporary name beside it
        exc.filename, exc.filename2 = str(path), None
        raise
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if tmp_path.exists():
            os.chmod(tmp_path, FILE_MODE)
        try:
            os.replace(tmp_path, path)
        except OSError as exc:  # "out: Is a directory", not the temporary name beside it
            exc.filename, exc.filename2 = str(path), None
            raise
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """``text`` as UTF-8; the undecodable bytes of a file name it mentions (surrogate
    escapes) as ``\\xNN`` (:mod:`capture2face.io.paths`)."""
    write_bytes_atomic(path, text.encode("utf-8", PATH_ERRORS))

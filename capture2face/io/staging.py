"""All-or-nothing output folders: a run writes into a hidden temporary folder beside its
final one and swaps it in only when every file is complete.

An interrupted or failed run (bad input found late, SIGINT, SIGTERM, a full disk) thus
leaves neither a half-written file nor a half-filled folder under the final name; folders
the run had to create for it are removed again when they stay empty.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from capture2face.errors import CaptureError
from capture2face.io.atomic import DIR_MODE

STAGING_PREFIX = ".tmp-"


def _make_parents(folder: Path) -> list[Path]:
    """``mkdir -p folder``; returns the folders it created, deepest last.

    Raises:
        CaptureError: the folder cannot be created (read-only, a file in the way, ...).
    """
    missing: list[Path] = []
    p = folder
    while not p.exists():
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    if p.exists() and not p.is_dir():
        raise CaptureError(f"cannot write to output folder {folder}: {p} is a file, not a folder")
    missing.reverse()
    for i, d in enumerate(missing):
        try:
            d.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            _remove_empty(missing[:i])
            raise CaptureError(f"cannot write to output folder {folder}: {exc.strerror or exc}") from None
    return missing


def _remove_empty(created: list[Path]) -> None:
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            break  # not empty (someone else wrote there) or already gone


@contextlib.contextmanager
def staged_folder(final: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``final``; on success it replaces ``final``.

    An existing ``final`` folder is replaced as a whole (old outputs never mix with new
    ones). On any exception, KeyboardInterrupt included, the temporary folder is deleted
    and so are the parent folders this call created.

    Raises:
        CaptureError: ``final``'s parent cannot be created or written, or ``final`` is a
            file.
    """
    final = Path(final)
    if final.exists() and not final.is_dir():
        raise CaptureError(f"cannot write outputs to {final}: it is a file, not a folder")
    created = _make_parents(final.parent)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{final.name}-", dir=final.parent))
    except OSError as exc:
        _remove_empty(created)
        raise CaptureError(f"cannot write to output folder {final.parent}: {exc.strerror or exc}") from None
    try:
        yield tmp
        os.chmod(tmp, DIR_MODE)  # mkdtemp made it owner-only
        old = None
        if final.exists():
            old = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}old-{final.name}-", dir=final.parent))
            os.replace(final, old / final.name)
        os.replace(tmp, final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        _remove_empty(created)
        raise


def check_writable(folder: str | os.PathLike) -> None:
    """Fail early (before any slow stage) when ``folder`` cannot take outputs.

    Creates nothing that outlives the call.
    """
    folder = Path(folder)
    created = _make_parents(folder)
    try:
        fd, probe = tempfile.mkstemp(prefix=STAGING_PREFIX, dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise CaptureError(f"cannot write to output folder {folder}: {exc.strerror or exc}") from None
    finally:
        _remove_empty(created)

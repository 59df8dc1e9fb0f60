"""The package's disk cache: one folder (``$CAPTURE2FACE_CACHE``, default
``~/.cache/capture2face``) of entries named by a key.

Entries are written atomically (a temporary file renamed onto the entry's name), so a
process reading while another writes sees the old entry, the new one or none, never half
of one; a damaged entry reads as absent and is built again; a cache that cannot be written
(read-only, full, a file where its folder should be) costs the next use the build, nothing
else.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from capture2face.errors import CaptureError
from capture2face.io.atomic import atomic_path

T = TypeVar("T")

# What reading a damaged or vanishing entry raises; writing to an unusable folder, too.
UNREADABLE = (OSError, ValueError, TypeError, CaptureError)
UNWRITABLE = (OSError, CaptureError)


def cache_dir() -> Path:
    """The cache folder (it need not exist yet)."""
    return Path(os.environ.get("CAPTURE2FACE_CACHE") or Path.home() / ".cache" / "capture2face")


def entry_path(name: str, folder: str = "") -> Path:
    """The path of entry ``name`` (e.g. ``<key>.rig.npz``) in the cache's sub-``folder``."""
    return cache_dir() / folder / name


def load_entry(path: Path, read: Callable[[Path], T],
               on_damaged: Callable[[Exception], None] | None = None) -> T | None:
    """``read(path)``, or None when the entry is absent or cannot be read (``on_damaged``
    is told why)."""
    if not path.is_file():
        return None
    try:
        return read(path)
    except UNREADABLE as exc:
        if on_damaged is not None:
            on_damaged(exc)
        return None


def store_entry(path: Path, write: Callable[[Path], None]) -> None:
    """``write`` the entry to a temporary path, then rename it onto ``path``; raises one of
    :data:`UNWRITABLE` when the cache cannot be written."""
    with atomic_path(path) as tmp:
        write(tmp)


def prune_entries(folder: Path, suffix: str, keep: int, companions: tuple[str, ...] = ()) -> None:
    """Only the ``keep`` most recently used ``*<suffix>`` entries of ``folder`` stay, each
    with its companion files (the same key with another suffix)."""
    entries = sorted(folder.glob(f"*{suffix}"), key=lambda p: p.stat().st_mtime_ns, reverse=True)
    for old in entries[keep:]:
        for path in (old, *(old.with_name(old.name.replace(suffix, c)) for c in companions)):
            path.unlink(missing_ok=True)

"""Which file a result was made from: size, modification time and a cheap content hash
(SHA-256 of the size and the first and last MiB), so that ``batch --resume`` notices a
clip or a character replaced by other content at the same path.

A run stores its inputs' fingerprints in report.json (``inputs``); :func:`changes` says
how a file differs from its stored fingerprint.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

CHUNK = 1 << 20  # the first and the last MiB are hashed


def fingerprint(path: str | os.PathLike) -> dict | None:
    """``{"path", "size", "mtime_ns", "sha256"}`` of the file ``path`` (None when it is not
    a readable file). ``path`` is stored absolute."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            st = os.fstat(fh.fileno())
            digest = hashlib.sha256(str(st.st_size).encode("ascii") + b"\0")
            digest.update(fh.read(CHUNK))
            if st.st_size > CHUNK:
                fh.seek(max(CHUNK, st.st_size - CHUNK))
                digest.update(fh.read(CHUNK))
    except OSError:
        return None
    return {"path": os.path.abspath(p), "size": int(st.st_size), "mtime_ns": int(st.st_mtime_ns),
            "sha256": digest.hexdigest()}


def changes(stored: Any, now: dict | None) -> list[str]:
    """How the file's fingerprint ``now`` differs from the ``stored`` one: "size 10 -> 12",
    "content", "modification time"; "gone", "new" when one of them is missing. [] when
    it is the same file content."""
    if not isinstance(stored, dict):
        return [] if now is None else ["new"]
    if now is None:
        return ["gone"]
    out = []
    if stored.get("size") != now["size"]:
        out.append(f"size {stored.get('size')} -> {now['size']}")
    if stored.get("sha256") != now["sha256"]:
        out.append("content")
    if stored.get("mtime_ns") != now["mtime_ns"]:
        out.append("modification time")
    return out

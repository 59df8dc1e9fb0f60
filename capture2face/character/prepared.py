"""A user's character prepared once: the imported rig with its landmark cast and baked maps,
cached on disk keyed on the files' content and the package's code.

The key hashes the .glb / .gltf, every file it references (external buffers and images),
the mapping JSON and the files that references (wrinkle maps, zone masks), and the
package's source, so any change to any of them prepares the character again; a rename or a
copy of the same files into another folder does not (the file's name is the rig's
name, so it counts). A cache entry is two files written atomically, the rig
last: ``<key>.rig.npz`` (:meth:`FaceRig.save`) and ``<key>.said.json`` (what the
preparation warned, said again on each use).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import urllib.parse
from pathlib import Path

from capture2face.io.cache import UNWRITABLE, cache_dir, load_entry, prune_entries, store_entry
from capture2face.rig.face_rig import FaceRig
from capture2face.runtime.log import log

_PACKAGE = Path(__file__).resolve().parents[1]
_CHUNK = 1 << 20
KEEP = 8  # prepared characters kept (the most recently used): each is 10-100 MB


@functools.lru_cache(maxsize=1)
def _code_hash() -> str:
    """Hash of every source file of the package (its version, in ``__init__.py``, too): new
    code, new entries."""
    h = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        h.update(path.relative_to(_PACKAGE).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _update_with_file(h, path: Path) -> None:
    h.update(os.fsencode(path.name))
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(_CHUNK), b""):
                h.update(block)
    except OSError:
        h.update(b"\0missing")  # the import says what is wrong with it


def referenced_files(path: Path) -> list[Path]:
    """Files a .gltf or a mapping JSON names by relative path: buffers and images (their
    URIs percent-decoded; data URIs are none), wrinkle maps and zone masks."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    if not isinstance(doc, dict):
        return []
    uris = [item.get("uri") for key in ("buffers", "images") for item in doc.get(key) or [] if isinstance(item, dict)]
    names = [urllib.parse.unquote(u) for u in uris if isinstance(u, str) and u and not u.startswith("data:")]
    maps = doc.get("wrinkle_maps")
    names += list(maps.values()) if isinstance(maps, dict) else []
    masks = doc.get("zone_masks")
    names += list(masks) if isinstance(masks, list) else []
    return [Path(path).parent / n for n in names if isinstance(n, str) and n]


def preparation_key(source: Path, mapping: Path | None) -> str:
    """Hex key of a character's files (``source`` .glb/.gltf, its ``mapping`` JSON or None)
    and of the package's code."""
    h = hashlib.sha256(_code_hash().encode())
    files = [source] + (referenced_files(source) if source.suffix.lower() == ".gltf" else [])
    if mapping is not None:
        files += [mapping] + referenced_files(mapping)
    for path in files:
        _update_with_file(h, path)
    return h.hexdigest()[:32]


def prepared_dir() -> Path:
    return cache_dir() / "characters"


def load_prepared(key: str) -> tuple[FaceRig, list[str]] | None:
    """The cached rig and its warnings, or None (absent, or unreadable: prepared again)."""
    rig_path, said_path = prepared_dir() / f"{key}.rig.npz", prepared_dir() / f"{key}.said.json"

    def read(path: Path) -> tuple[FaceRig, list[str]]:
        said = json.loads(said_path.read_text(encoding="utf-8"))
        rig = FaceRig.load(path)
        os.utime(path)  # recently used: kept by pruning
        return rig, [str(s) for s in said]

    return load_entry(rig_path, read, lambda exc: log.debug("prepared character %s unreadable (%s): preparing it "
                                                             "again", key, exc))


def store_prepared(key: str, rig: FaceRig, said: list[str]) -> None:
    """Keep ``rig`` (and what its preparation warned) for the next use; a cache that
    cannot be written costs the next run the preparation, nothing else."""
    try:
        store_entry(prepared_dir() / f"{key}.said.json", lambda tmp: tmp.write_bytes(json.dumps(said).encode()))
        store_entry(prepared_dir() / f"{key}.rig.npz", rig.save)  # last: the entry is complete once it is there
        prune_entries(prepared_dir(), ".rig.npz", KEEP, (".said.json",))
    except UNWRITABLE as exc:
        log.warning("cannot cache the prepared character in %s (%s); it is prepared again next time",
                    prepared_dir(), exc)

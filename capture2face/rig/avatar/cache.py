"""The default avatar on demand: built on first use, then kept in memory and in the disk
cache (:mod:`capture2face.io.cache`) as ``avatar-<variant>-<hash>.rig.npz``; the hash
covers the source of every builder module, so a code change rebuilds it."""

from __future__ import annotations

import contextlib
import functools
import hashlib
from pathlib import Path

from capture2face.errors import CaptureError
from capture2face.io.cache import UNWRITABLE, entry_path, load_entry, store_entry
from capture2face.rig.avatar.build import build_avatar
from capture2face.rig.avatar.variants import VARIANTS
from capture2face.rig.face_rig import FaceRig

_RIG_DIR = Path(__file__).resolve().parents[1]
# The rig modules the builder uses beside its own package's.
_BUILDER_SOURCES = ("canonical.py", "features.py", "mesh_ops.py", "maps.py", "face_rig.py")


@functools.cache
def _source_hash() -> str:
    """Hash of the builder's source files: a code change gives a new cache file."""
    h = hashlib.sha256()
    for path in [_RIG_DIR / name for name in _BUILDER_SOURCES] + sorted(Path(__file__).parent.glob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


_MEMO: dict[str, FaceRig] = {}


def _cache_key(variant: str | None) -> str:
    return f"{variant or 'default'}-{_source_hash()}"


def _cache_path(key: str) -> Path:
    return entry_path(f"avatar-{key}.rig.npz")


def forget_built() -> None:
    """Drop the avatars kept in memory (the next :func:`default_avatar` reads the disk
    cache or builds)."""
    _MEMO.clear()


def is_cached(variant: str | None = None) -> bool:
    """Whether :func:`default_avatar` has this variant at hand (in memory or on disk)
    rather than building it (~5 s)."""
    key = _cache_key(variant)
    return key in _MEMO or _cache_path(key).is_file()


def default_avatar(variant: str | None = None) -> FaceRig:
    """The default avatar (``variant=None`` or ``"default"``) or a built-in variant
    (``"wide"``: face 15% wider, brows 0.5 cm higher, longer chin, longer nose: another
    morphology with the same topology, bones and morphs).

    Built on first use and cached on disk and in memory.
    """
    variant = variant or "default"
    if variant not in VARIANTS:
        raise CaptureError(f"unknown avatar variant '{variant}' (choose from {', '.join(VARIANTS)})")
    key = _cache_key(variant)
    if key in _MEMO:
        return _MEMO[key]
    path = _cache_path(key)
    rig = load_entry(path, FaceRig.load)  # a corrupt cache file is rebuilt
    if rig is None:
        rig = build_avatar(variant)
        with contextlib.suppress(UNWRITABLE):  # a read-only cache still gives the rig, just not cached
            store_entry(path, rig.save)
    _MEMO[key] = rig
    return rig

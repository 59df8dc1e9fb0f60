"""Keep a long run's resident memory flat: glibc malloc settings (Linux; no-op elsewhere).

glibc raises its mmap threshold to the size of the largest block freed so far (up to
32 MiB). After the retarget windows (~10 MB arrays), every video frame the render threads
allocate then comes from the heap arenas instead of its own mapping, and over thousands
of frames the arenas fragment: measured, ~3 KB of resident memory per frame of a
10-minute clip with nothing alive to show for it. Fixing the threshold at glibc's initial
128 KiB keeps big blocks in their own mappings, returned to the system when freed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import sys

M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter numbers
MMAP_THRESHOLD_BYTES = 128 * 1024

_libc = None


def _glibc():
    global _libc
    if _libc is None:
        _libc = False
        if sys.platform.startswith("linux"):
            try:
                lib = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                if hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim"):
                    _libc = lib
            except OSError:
                pass
    return _libc or None


def bound_heap() -> bool:
    """Fix malloc's mmap threshold for this process (see module doc); True if applied."""
    lib = _glibc()
    return bool(lib and lib.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


def release_free_memory() -> None:
    """Collect garbage and hand the heap's free pages back to the system (between stages)."""
    gc.collect()
    lib = _glibc()
    if lib:
        lib.malloc_trim(0)

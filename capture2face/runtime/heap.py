"""Keep a long run's resident memory flat: glibc malloc settings (Linux; no-op elsewhere).

glibc raises its mmap threshold to the size of the largest block freed so far (up to
32 MiB), so after the retarget windows (~10 MB arrays) blocks of every size come from the
heap arenas, where they fragment: measured at 256 px, the render pass of a 2-minute clip
grew 11 MB more than that of a 10-second one, and the retarget pass left ~10 MB of free
but resident heap behind. A fixed threshold of 4 MiB (which also turns the adjustment
off) keeps window-sized arrays in their own mappings, returned to the system when freed,
while video frames up to 4 MiB (a 512 px compare frame is 2.4 MB) stay in the arenas:
mapping each frame afresh would cost ~0.5 ms of page faults per frame. The trim threshold
goes to twice that, as glibc's own adjustment would set it (at its default of 128 KiB,
freeing a frame at the top of the heap hands its pages back, and the next frame faults
them in again). Measured: the render pass then grows by the same amount for both clips.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import sys

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameter numbers
MMAP_THRESHOLD_BYTES = 4 << 20
TRIM_THRESHOLD_BYTES = 8 << 20  # glibc's own rule when it moves the threshold: twice it

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
    return bool(lib and lib.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                and lib.mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def release_free_memory() -> None:
    """Collect garbage and hand the heap's free pages back to the system (between stages)."""
    gc.collect()
    lib = _glibc()
    if lib:
        lib.malloc_trim(0)

"""The one OpenGL context of the process: headless EGL (the GPU where there is one,
Mesa llvmpipe otherwise), created on first use and shared by every renderer."""

from __future__ import annotations

import threading

import moderngl

from capture2face.errors import CaptureError

_lock = threading.Lock()
_context: moderngl.Context | None = None


def gl_context() -> moderngl.Context:
    """The shared standalone context (OpenGL 3.3 core or newer)."""
    global _context
    with _lock:
        if _context is None:
            try:
                _context = moderngl.create_standalone_context(backend="egl", require=330)
            except Exception as exc:  # moderngl raises plain Exception for EGL failures
                raise CaptureError(
                    f"cannot create a headless OpenGL context through EGL ({exc}); "
                    "install Mesa's EGL (libegl1, libgl1-mesa-dri) or a GPU driver"
                ) from None
        return _context


def gl_renderer() -> str:
    """The GL_RENDERER string of the shared context (e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)')."""
    return str(gl_context().info["GL_RENDERER"])


def software_gl() -> bool:
    """True when the context rasterizes on the CPU (Mesa llvmpipe, softpipe, swrast), where
    per-pixel work such as MSAA costs what a GPU gets for free."""
    name = gl_renderer().lower()
    return any(key in name for key in ("llvmpipe", "softpipe", "swrast"))

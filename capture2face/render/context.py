"""The one OpenGL context of the process: headless EGL (the GPU where there is one,
Mesa llvmpipe otherwise), created on first use and shared by every renderer."""

from __future__ import annotations

import ctypes.util
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
            missing = missing_gl_library()
            if missing:
                raise CaptureError(missing)
            try:
                _context = moderngl.create_standalone_context(backend="egl", require=330)
            except Exception as exc:  # moderngl raises plain Exception for EGL failures
                reason = " ".join(str(exc).split()) or exc.__class__.__name__
                raise CaptureError(
                    f"cannot create a headless OpenGL 3.3 context through EGL ({reason}); install "
                    f"Mesa's drivers ({MESA_PACKAGES}) or a GPU driver"
                ) from None
        return _context


# Debian/Ubuntu packages of what the EGL backend loads: libEGL.so.1 (libegl1, which pulls
# in Mesa's EGL vendor libegl-mesa0), libGL.so.1 (libgl1) and Mesa's software and
# hardware drivers (libgl1-mesa-dri: llvmpipe).
MESA_PACKAGES = "Debian/Ubuntu: apt-get install libegl1 libgl1 libgl1-mesa-dri"
_GL_LIBRARIES = (("EGL", "libEGL.so.1", "libegl1"), ("GL", "libGL.so.1", "libgl1"))


def missing_gl_library() -> str | None:
    """One line naming the system library the EGL backend needs and cannot find (moderngl's
    glcontext loads them by ``ctypes.util.find_library``), or None when both are there."""
    for name, soname, package in _GL_LIBRARIES:
        if not ctypes.util.find_library(name):  # looked up at call time (tests patch it)
            return (f"cannot render: the system library {soname} is missing; install {package} "
                    f"and Mesa's drivers ({MESA_PACKAGES}) or a GPU driver")
    return None


def gl_renderer() -> str:
    """The GL_RENDERER string of the shared context (e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)')."""
    return str(gl_context().info["GL_RENDERER"])


def software_gl() -> bool:
    """True when the context rasterizes on the CPU (Mesa llvmpipe, softpipe, swrast), where
    per-pixel work such as MSAA costs what a GPU gets for free."""
    name = gl_renderer().lower()
    return any(key in name for key in ("llvmpipe", "softpipe", "swrast"))

"""Errors a user can fix (the CLI prints them as one line and exits with code 2), and the
process set-up that makes interruptions clean."""

import atexit
import contextlib
import os
import signal
import sys


class CaptureError(Exception):
    """Bad input or an impossible request: a missing file, not a video, no face, ...

    The message is shown to the user as is, so it says what is wrong and what to do.
    """

    exit_code = 2


class NoFaceError(CaptureError):
    """A clip in which the tracker found no face at all (a caller that made the clip, such
    as ``eval synthetic --actor``, names the cause: its actor)."""


_interrupted = False


def _raise_interrupt(signum, frame):
    global _interrupted
    _interrupted = True
    raise KeyboardInterrupt


def raise_if_interrupted() -> None:
    """Raise KeyboardInterrupt if SIGINT or SIGTERM has arrived.

    Python drops an exception raised inside a finalizer or a weakref callback ("Exception
    ignored in ..."), so a signal that lands there would be lost and the run would finish
    as if nothing had happened. The handler also sets a flag, and the stages call this
    between frames and between stages.
    """
    if _interrupted:
        raise KeyboardInterrupt


def _unraisable(info) -> None:
    """An interrupt swallowed by a finalizer is not an error to print: the flag keeps it.
    Nor, once interrupted, is a finalizer's error: the interrupt may have cut its object's
    construction short (MediaPipe's ``Image.__del__`` then misses ``_image_ptr``)."""
    if isinstance(info.exc_value, KeyboardInterrupt) or _interrupted:
        return
    sys.__unraisablehook__(info)


def install_process_defaults() -> None:
    """For the CLI and each batch worker: SIGINT and SIGTERM unwind like Ctrl-C (and are
    remembered, see :func:`raise_if_interrupted`), so staged and atomic writers delete their
    temporary files; MediaPipe's and TFLite's C++ logs stay quiet."""
    signal.signal(signal.SIGINT, _raise_interrupt)
    signal.signal(signal.SIGTERM, _raise_interrupt)
    sys.unraisablehook = _unraisable
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")


def exit_interrupted() -> None:
    """End this process now with exit code 130 (interrupted), after its exit handlers.

    CPython ends a process by SIGINT, whatever exit code it was given, once a
    KeyboardInterrupt has left an ``exec`` or ``eval`` of a string (a dataclass being
    defined while a module imports, say), even where the program caught it afterwards: a
    signal landing there turned the command's 130 into a death by SIGINT. Only for the
    process that is the command (its staged outputs are already cleaned up by then).
    """
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(130)

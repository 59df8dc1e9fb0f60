"""Errors a user can fix (the CLI prints them as one line and exits with code 2), and the
process set-up that makes interruptions clean."""

import os
import signal


class CaptureError(Exception):
    """Bad input or an impossible request: a missing file, not a video, no face, ...

    The message is shown to the user as is, so it says what is wrong and what to do.
    """

    exit_code = 2


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def install_process_defaults() -> None:
    """For the CLI and each batch worker: SIGTERM unwinds like Ctrl-C, so staged and atomic
    writers delete their temporary files; MediaPipe's and TFLite's C++ logs stay quiet."""
    signal.signal(signal.SIGTERM, _raise_interrupt)
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

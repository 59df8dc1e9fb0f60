"""The ``capture2face`` command and ``python -m capture2face``: Ctrl-C while the libraries
load (seconds, on this module's import) ends like Ctrl-C later, in one line with exit 130."""

import os
import signal
import sys


def _interrupted(signum, frame) -> None:
    """Ctrl-C before the command's own handler exists: the same one line and exit 130 as
    later (os._exit: after an interrupted import CPython would end by SIGINT, see
    errors.exit_interrupted)."""
    print("capture2face: interrupted", file=sys.stderr, flush=True)
    os._exit(130)


# Python's own handler only: a SIGINT ignored (a background job of sh) stays ignored.
_PREVIOUS = signal.getsignal(signal.SIGINT)
if _PREVIOUS is signal.default_int_handler:
    signal.signal(signal.SIGINT, _interrupted)
from capture2face.cli import main  # noqa: E402  (after the handler: the import takes seconds)

signal.signal(signal.SIGINT, _PREVIOUS)
__all__ = ["main"]

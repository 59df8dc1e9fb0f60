"""The ``capture2face`` logger, and the warnings of a piece of work collected for its report.

One channel for every warning: the logger. A piece of work that reports (a run: its
report.json, which ``capture2face run`` prints) collects them with
:func:`collect_warnings`; outside one, the command line prints them as they come
(:func:`warnings_to_stderr`), as ``capture2face: warning: ...``.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading

log = logging.getLogger("capture2face")

WARNING_PREFIX = "capture2face: warning: "

_lock = threading.Lock()
_reporting = [0]  # collectors open whose work reports (and prints) what they collect


class WarningLog(logging.Handler):
    """Collects the ``capture2face`` logger's warnings during a run for report.json."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


@contextlib.contextmanager
def collect_warnings(reported: bool = True):
    """The warnings said inside the block, as a list. ``reported``: the caller reports them
    (a run's report.json, printed by the command line), so they are not printed as they
    come; False only records them (what a character's preparation said, said again each
    time the prepared copy is used)."""
    handler = WarningLog()
    log.addHandler(handler)
    if reported:
        with _lock:
            _reporting[0] += 1
    try:
        yield handler.messages
    finally:
        if reported:
            with _lock:
                _reporting[0] -= 1
        log.removeHandler(handler)


class _Stderr(logging.Handler):
    """Prints a warning no report carries: ``capture2face: warning: <message>``."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)

    def emit(self, record: logging.LogRecord) -> None:
        if _reporting[0]:
            return  # the report says it (and ``run`` prints the report's warnings)
        with contextlib.suppress(OSError, ValueError):  # stderr closed: a warning is not worth a failure
            print(WARNING_PREFIX + record.getMessage(), file=sys.stderr, flush=True)


def warnings_to_stderr() -> None:
    """For the command line and its worker processes: warnings outside a reported piece of
    work are printed with the prefix (instead of Python's bare last-resort line). Once per
    process."""
    if not any(isinstance(h, _Stderr) for h in log.handlers):
        log.addHandler(_Stderr())

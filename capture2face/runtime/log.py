"""The ``capture2face`` logger, and the warnings of a piece of work collected for its report."""

from __future__ import annotations

import contextlib
import logging

log = logging.getLogger("capture2face")


class WarningLog(logging.Handler):
    """Collects the ``capture2face`` logger's warnings during a run for report.json."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


@contextlib.contextmanager
def collect_warnings():
    handler = WarningLog()
    log.addHandler(handler)
    try:
        yield handler.messages
    finally:
        log.removeHandler(handler)


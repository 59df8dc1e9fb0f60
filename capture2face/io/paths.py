"""File names that are not valid UTF-8 (``café.mp4`` written in Latin-1): Python holds
their undecodable bytes as surrogate escapes (``'caf\\udce9.mp4'``), which a UTF-8 encoder
refuses. Everything the project writes about a path (report.json, report.html,
batch_report.json, the lines it prints) goes through :func:`readable` or the
``"capture2face-path"`` codec error handler, which write such bytes as ``\\xe9`` escapes
instead of failing.
"""

from __future__ import annotations

import codecs
import contextlib
import sys

ERRORS = "capture2face-path"


def _escape(exc: UnicodeError):
    """Codec error handler: a surrogate-escaped byte (U+DC80..U+DCFF) as ``\\xNN``, any
    other unencodable character as ``\\uNNNN``."""
    if not isinstance(exc, UnicodeEncodeError):
        raise exc
    out = []
    for ch in exc.object[exc.start:exc.end]:
        code = ord(ch)
        out.append(f"\\x{code - 0xDC00:02x}" if 0xDC80 <= code <= 0xDCFF else f"\\u{code:04x}")
    return "".join(out), exc.end


codecs.register_error(ERRORS, _escape)


def readable(text: str) -> str:
    """``text`` with surrogate escapes written as ``\\xNN`` (encodable as UTF-8); other
    text unchanged."""
    return text.encode("utf-8", ERRORS).decode("utf-8")


def readable_streams() -> None:
    """stdout and stderr write undecodable bytes of file names as ``\\xNN`` rather than
    raising UnicodeEncodeError (stdout's default) in the middle of a command."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            # A stream that cannot change (closed, replaced by a test's capture) stays as it is.
            with contextlib.suppress(ValueError, OSError):
                reconfigure(errors=ERRORS)

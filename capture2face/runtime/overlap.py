"""Overlapped stages: worker threads joined by bounded queues, stopped together.

The pipeline's second pass decodes the source, renders (in the thread that owns the GL
context) and encodes two videos at once. PyAV, OpenCV and large NumPy operations release
the GIL, so threads overlap well on a few cores, and bounded queues keep memory flat
whatever the clip's length.

One error anywhere (a worker's exception, KeyboardInterrupt in the main thread) stops
every stage: blocked ``put``/``get`` calls wake up and raise :class:`Cancelled`, the
workers unwind through their ``with`` blocks (so atomic writers delete their temporary
files), and the first real error is re-raised in the main thread.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from typing import Any

_POLL_S = 0.05
_END = object()


class Cancelled(Exception):
    """Raised inside a stage when another stage failed or the run was interrupted."""


class Channel:
    """A bounded FIFO between two stages that gives up when the group stops."""

    def __init__(self, group: StageGroup, maxsize: int):
        self._q: queue.Queue = queue.Queue(maxsize)
        self._group = group

    def put(self, item: Any) -> None:
        while True:
            self._group.raise_if_stopped()
            try:
                self._q.put(item, timeout=_POLL_S)
                return
            except queue.Full:
                continue

    def get(self) -> Any:
        while True:
            self._group.raise_if_stopped()
            try:
                return self._q.get(timeout=_POLL_S)
            except queue.Empty:
                continue

    def close(self) -> None:
        """Tell the consumer that no more items come."""
        self.put(_END)

    def __iter__(self) -> Iterator[Any]:
        while True:
            item = self.get()
            if item is _END:
                return
            yield item


class StageGroup:
    """Context manager owning a set of worker threads and the channels between them.

    ``with StageGroup() as g: ...`` — on leaving the block normally it waits for every
    worker and re-raises the first worker error; on an exception it stops them first.
    """

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._errors: list[BaseException] = []
        self._lock = threading.Lock()

    def channel(self, maxsize: int = 8) -> Channel:
        return Channel(self, maxsize)

    def spawn(self, name: str, fn: Callable[..., Any], *args: Any) -> None:
        def body() -> None:
            try:
                fn(*args)
            except Cancelled:
                pass
            except BaseException as exc:  # re-raised in the main thread
                with self._lock:
                    self._errors.append(exc)
                self._stop.set()

        t = threading.Thread(target=body, name=f"capture2face-{name}", daemon=True)
        self._threads.append(t)
        t.start()

    def raise_if_stopped(self) -> None:
        if self._stop.is_set():
            raise Cancelled()

    def stop(self) -> None:
        self._stop.set()

    def join(self) -> None:
        """Wait for every worker; re-raise the first worker error."""
        for t in self._threads:
            while t.is_alive():
                t.join(_POLL_S)  # short waits keep Ctrl-C responsive in the main thread
        if self._errors:
            raise self._errors[0]

    def __enter__(self) -> StageGroup:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.join()
            return False
        self._stop.set()
        for t in self._threads:
            while t.is_alive():
                try:
                    t.join(_POLL_S)
                except KeyboardInterrupt:  # a second Ctrl-C while unwinding: keep unwinding
                    continue
        if exc_type is Cancelled and self._errors:
            raise self._errors[0]  # the main thread only saw the consequence; show the cause
        return False

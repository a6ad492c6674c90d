"""SIGTERM as an exception, so that a terminated command unwinds like an interrupted
one: open `with` blocks remove their partial output files before the process ends."""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator


class Terminated(BaseException):
    """The process was sent SIGTERM (a BaseException, like KeyboardInterrupt, so that
    handlers of ordinary errors do not swallow it)."""


def _raise(signum, frame) -> None:
    raise Terminated()


@contextlib.contextmanager
def terminate_as_exception() -> Iterator[None]:
    """Within the block, SIGTERM raises Terminated; the previous handler is restored
    afterwards. Only the main thread can handle signals: elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)

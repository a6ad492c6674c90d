"""SIGTERM as an exception, so that a terminated command unwinds like an interrupted
one: open `with` blocks remove their partial output files before the process ends."""

from __future__ import annotations

import contextlib
import functools
import os
import select
import signal
import sys
import threading
from typing import BinaryIO, Iterator


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


class _StandardInput:
    """Standard input whose reads wait for data in short select() steps, so that SIGTERM
    or Ctrl-C end a wait promptly: a signal can be delivered to a thread a library
    started (a BLAS pool), and a main thread blocked in read() would not see it until
    more data came. Buffered here, so that bytes peeked at are read again."""

    def __init__(self, fd: int):
        self._fd = fd
        self._buf = bytearray()
        self._eof = False

    def _fill(self) -> bool:
        if self._eof:
            return False
        # Python runs its signal handlers between these steps
        while not select.select([self._fd], [], [], 0.1)[0]:
            pass
        chunk = os.read(self._fd, 1 << 16)
        self._eof = not chunk
        self._buf += chunk
        return bool(chunk)

    def peek(self, size: int = 1) -> bytes:
        while len(self._buf) < max(size, 1) and self._fill():
            pass
        return bytes(self._buf)

    def read(self, size: int | None = -1) -> bytes:
        if size is None or size < 0:
            while self._fill():
                pass
            size = len(self._buf)
        while len(self._buf) < size and self._fill():
            pass
        data = bytes(self._buf[:size])
        del self._buf[:size]
        return data

    def fileno(self) -> int:
        return self._fd


@functools.cache
def standard_input() -> BinaryIO:
    """The command's standard input as a binary stream (one per process, so that what
    one reader peeks at another still reads); interruptible where select() works on
    pipes (POSIX), sys.stdin.buffer elsewhere."""
    if os.name != "posix":
        return sys.stdin.buffer
    return _StandardInput(sys.stdin.fileno())

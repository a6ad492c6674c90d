"""Running `atm` with one of its output streams on a pseudo-terminal."""

from __future__ import annotations

import os
import pty
import subprocess
import sys


def run_on_a_terminal(*args, stream: str = "stderr") -> tuple[int, bytes, bytes]:
    """Run atm with `stream` ("stderr" or "stdout") on a pseudo-terminal; return
    (status, what reached the terminal, standard error's bytes when that is not it)."""
    master, slave = pty.openpty()
    # standard output off the terminal is discarded: unread, a pipe could fill and block
    ends = {"stdout": subprocess.DEVNULL, "stderr": subprocess.PIPE, stream: slave}
    proc = subprocess.Popen([sys.executable, "-m", "codec", *map(str, args)], **ends)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # the other side closed
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    other = proc.stderr.read() if stream == "stdout" else b""
    return proc.wait(), b"".join(chunks), other

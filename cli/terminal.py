"""Binary data is not written to a terminal: it garbles the screen and can send the
terminal control codes. Refused as zstd and gzip refuse it, unless --force."""

from __future__ import annotations

import sys
from typing import BinaryIO

from .outputs import UsageError


def refuse_binary_to_terminal(output: str, what: str, force: bool, stream: BinaryIO | None = None) -> None:
    """UsageError if `output` is - (standard output), standard output is a terminal and
    `force` is not set; `what` names the data ("the .atm file", "the PNG image")."""
    if output != "-" or force:
        return
    stream = stream or sys.stdout
    try:
        tty = stream.isatty()
    except (AttributeError, ValueError):  # closed or not a real file
        return
    if tty:
        raise UsageError(
            f"standard output is a terminal; {what} would be written to it as binary data: "
            "redirect it (> FILE, | COMMAND), give an output file, or --force"
        )

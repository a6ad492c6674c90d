"""Checks made before a command writes anything: the output is none of the inputs, and
its name does not claim a different kind of file than the bytes it will hold."""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

from codec.errors import ATMError
from codec.files import IMAGE_NAMES


class UsageError(ATMError):
    """The arguments do not make sense together (exit status 2)."""


def identity(name: str, stream=None) -> tuple[int, int] | None:
    """(st_dev, st_ino) of the regular file `name` is (or `stream` is, for -), following
    links; None for anything else (a missing file, a pipe, a terminal, a device)."""
    try:
        st = os.fstat(stream.fileno()) if name == "-" else os.stat(name)
    except (OSError, ValueError, AttributeError):
        return None
    return (st.st_dev, st.st_ino) if stat.S_ISREG(st.st_mode) else None


def refuse_overwriting_inputs(inputs: list[str], outputs: list[str]) -> None:
    """UsageError if an output is one of the inputs: the same file by name, hard link or
    symbolic link (standard input and output count as the files they are redirected to)."""
    sources = {}
    for name in inputs:
        key = identity(str(name), sys.stdin)
        if key is not None:
            sources.setdefault(key, str(name))
    for name in outputs:
        key = identity(str(name), sys.stdout)
        if key in sources:
            src = sources[key]
            same = "is" if os.path.abspath(src) == os.path.abspath(name) else "is the same file as"
            raise UsageError(
                f"the output {name} {same} the input {src}; writing it would destroy the input: "
                "choose another output name"
            )


def refuse_misleading_name(output: str, writes_atm: bool, force: bool, what: str = "") -> None:
    """UsageError if `output` is named as an image but gets .atm bytes, or named .atm but
    gets something else (`what`), unless `force`: such a file is opened with the wrong
    program, and the .atm name may be an encoded file the user means to keep."""
    if not output:
        raise UsageError("the output file name is empty")
    if force or output == "-":
        return
    suffix = Path(output).suffix.lower()
    stem = output[: len(output) - len(suffix)]
    if writes_atm and suffix in IMAGE_NAMES:
        raise UsageError(
            f"{output} is named as a {suffix} image, but the output is an .atm file: "
            f"name it {stem}.atm, or give --force to write .atm data under this name"
        )
    if not writes_atm and suffix == ".atm":
        raise UsageError(
            f"{output} is named as an .atm file, but the output is {what or 'not .atm data'}: "
            f"give an output name with that kind's extension, or --force (with --format) "
            "to write it under this name"
        )

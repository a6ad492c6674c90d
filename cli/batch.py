"""Batch conversion: many images to .atm (or back) in one command, on a process pool.

The rule (also in `atm encode --help`): the command works in batch when it is given more
than one input, or one input that is a directory or a glob pattern (`*`, `?` or `[`, and
no file of that exact name), or when the last argument is an existing directory. The
last argument is then an output directory, created if missing; each input X becomes OUTDIR/X-stem.atm (encode) or OUTDIR/X-stem.png (decode,
or the --format). A file that fails is reported and the others still convert; the exit
status is 1 if any failed. Ctrl-C or SIGTERM stops the workers at once: files not yet
finished are not written, then or later.
"""

from __future__ import annotations

import argparse
import glob
import os
import signal
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

from . import convert, outputs, signals
from .outputs import UsageError
from .progress import Progress
from codec.errors import ATMError
from codec.files import IMAGE_SUFFIXES

GLOB_CHARS = set("*?[")
WORKER_DIED = "not converted: a worker process ended abruptly (killed, out of memory, or a crash); rerun it with --jobs 1"


def is_batch(inputs: list[str], output: str) -> bool:
    """Whether the command converts into a directory: several inputs, an input that is
    a directory or a glob pattern, or an output that is an existing directory."""
    if len(inputs) != 1:
        return True
    name = inputs[0]
    if name == "-":
        return False
    return (
        os.path.isdir(name)
        or (bool(GLOB_CHARS & set(name)) and not os.path.exists(name))
        or os.path.isdir(output)
    )


def expand(inputs: list[str], command: str) -> list[Path]:
    """The input files, in order, each once: directories give their image files
    (encode) or .atm files (decode), patterns the files they match."""
    suffixes = IMAGE_SUFFIXES if command == "encode" else {".atm"}
    found: list[Path] = []
    for name in inputs:
        if name == "-":
            raise UsageError("standard input (-) cannot be one of several inputs")
        if os.path.isdir(name):
            # hidden files are skipped: they include atomic writes still in progress
            found += sorted(
                p for p in Path(name).iterdir()
                if p.is_file() and p.suffix.lower() in suffixes and not p.name.startswith(".")
            )
        elif os.path.exists(name):
            found.append(Path(name))
        elif GLOB_CHARS & set(name):
            found += sorted(Path(p) for p in glob.glob(name) if os.path.isfile(p))
        else:
            raise ATMError(f"cannot read {name}: No such file or directory")
    unique = list(dict.fromkeys(found))
    if not unique:
        kinds = "images" if command == "encode" else ".atm files"
        raise ATMError(f"no {kinds} in {' '.join(inputs)}")
    return unique


def plan(files: list[Path], outdir: Path, suffix: str) -> list[tuple[Path, Path]]:
    """(input, output) pairs; two inputs that would write one output, or an output that
    is one of the inputs, are refused before anything is converted, since one would
    silently replace the other."""
    pairs = [(f, outdir / (f.stem + suffix)) for f in files]
    seen: dict[Path, Path] = {}
    for src, dst in pairs:
        if dst in seen:
            raise ATMError(f"{seen[dst]} and {src} would both be written to {dst}; convert them separately")
        seen[dst] = src
    outputs.refuse_overwriting_inputs([str(f) for f in files], [str(d) for _, d in pairs])
    return pairs


@dataclass
class Result:
    """How one file's conversion went."""

    source: str
    ok: bool
    bytes_in: int = 0
    bytes_out: int = 0
    error: str = ""


def convert_one(command: str, src: str, dst: str, options: dict) -> Result:
    """Convert one file; every failure becomes a Result so that the batch goes on."""
    try:
        size = os.path.getsize(src)
        if command == "encode":
            written = convert.encode_file(src, dst, options["encode"])[1]
        else:
            written = convert.decode_file(src, dst, options["format"], options["backend"])
        return Result(src, True, size, written)
    except ATMError as exc:
        return Result(src, False, error=str(exc))
    except OSError as exc:
        return Result(src, False, error=f"{exc.strerror or exc}")
    except Exception as exc:  # a bug on one file must not stop the others converting
        return Result(src, False, error=f"internal error ({type(exc).__name__}: {exc}); rerun it alone with --debug")


def _worker_setup() -> None:
    # Ctrl-C reaches the whole process group: the main process alone decides what stops
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # an idle worker just ends on SIGTERM (a forked one inherits the parent's handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # each worker is one of --jobs processes: OpenCV's own thread pool would oversubscribe
    import cv2

    cv2.setNumThreads(1)


def _work(command: str, src: str, dst: str, options: dict) -> Result:
    """convert_one in a worker; terminated, the worker leaves at once (the conversion's
    `with` blocks have removed its partial file) instead of taking the next file."""
    try:
        with signals.terminate_as_exception():
            return convert_one(command, src, dst, options)
    except signals.Terminated:
        os._exit(128 + signal.SIGTERM)


def _stop(pool: ProcessPoolExecutor, grace: float = 2.0) -> None:
    """Cancel the files not started and end the workers converting the others."""
    # ProcessPoolExecutor has no public way to end its workers before Python 3.14's
    # terminate_workers(); without this, shutdown waits for every running conversion
    workers = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown forgets it
    pool.shutdown(wait=False, cancel_futures=True)
    for p in workers:
        p.terminate()  # SIGTERM: the worker's partial output is removed as it exits
    deadline = time.monotonic() + grace
    for p in workers:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join()
    # the executor's manager thread closes its wake-up pipe once it sees the workers
    # gone; at exit Python writes to that pipe unlocked, so a thread still closing it
    # then races the write ("Bad file descriptor" on stderr): let it finish first
    if manager is not None:
        manager.join(grace)


def run(args: argparse.Namespace, command: str) -> int:
    """Convert every input of a batch command; print failures, a summary, and return
    the exit status."""
    if not args.output:
        raise UsageError("the output directory name is empty")
    outdir = Path(args.output)
    if outdir.exists() and not outdir.is_dir():
        raise UsageError(f"{outdir} is a file; in batch mode the last argument is an output directory")
    if command == "encode":
        options = {"encode": convert.encode_options(args)}
        suffix = ".atm"
    else:
        fmt = args.format or "png"
        options = {"format": fmt, "backend": args.backend}
        suffix = "." + fmt
    # checked before the output directory is made: a usage error leaves nothing behind
    jobs = args.jobs if args.jobs is not None else os.cpu_count() or 1
    if jobs < 1:
        raise UsageError(f"--jobs must be at least 1, not {jobs}")
    pairs = plan(expand(args.inputs, command), outdir, suffix)
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ATMError(f"cannot create {outdir}: {exc.strerror}") from None
    bar = Progress(len(pairs), quiet=args.quiet)
    start = time.monotonic()
    results: list[Result] = []

    def record(r: Result) -> None:
        results.append(r)
        if not r.ok:
            # most codec messages already start with the file's name
            where = "" if r.error.startswith(r.source) else f"{r.source}: "
            bar.message(f"atm: error: {where}{r.error}")
        bar.update(len(results), f"{len(results)}/{len(pairs)} {Path(r.source).name}")

    bar.update(0, f"0/{len(pairs)}")
    if jobs == 1 or len(pairs) == 1:
        for src, dst in pairs:
            record(convert_one(command, str(src), str(dst), options))
    else:
        pool = ProcessPoolExecutor(min(jobs, len(pairs)), initializer=_worker_setup)
        try:
            sources = {pool.submit(_work, command, str(s), str(d), options): str(s) for s, d in pairs}
            pending = set(sources)
            while pending:
                # short waits: Python runs a SIGINT/SIGTERM handler between them even when
                # the signal went to a thread a library started (cli/signals.py)
                done, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
                for future in done:
                    try:
                        record(future.result())
                    except BrokenProcessPool:
                        # a worker died (killed, out of memory, a crash in native code):
                        # the pool is gone, and with it every file not yet converted
                        record(Result(sources[future], False, error=WORKER_DIED))
        except BaseException:
            # Ctrl-C or SIGTERM: no file may be written after the command has stopped
            _stop(pool)
            raise
        pool.shutdown()
    bar.clear()
    failed = [r for r in results if not r.ok]
    ok = [r for r in results if r.ok]
    if not args.quiet:
        bytes_in, bytes_out = sum(r.bytes_in for r in ok), sum(r.bytes_out for r in ok)
        verb = "encoded" if command == "encode" else "decoded"
        print(
            f"atm: {verb} {len(ok)} of {len(results)} file(s) into {outdir}, {len(failed)} failed; "
            f"{bytes_in:,} bytes in, {bytes_out:,} bytes out, {time.monotonic() - start:.1f} s",
            file=sys.stderr,
        )
    if failed:
        names = ", ".join(r.source for r in failed)
        print(f"atm: error: {len(failed)} of {len(results)} file(s) failed: {names}", file=sys.stderr)
        return 1
    return 0

"""Every command README.md shows runs, in the order shown, in a scratch folder, and
prints what the README says it prints: the README cannot drift from the tool.

Fenced `sh` and `console` blocks are run (in `console` blocks, `$ ` lines are commands
and the lines under them their expected output), then the `python` blocks, with the
arrays they name made by the test; `text` blocks are synopses. Only the
fresh-machine block is marked (`<!-- readme-test: ... -->`): its install and pytest
steps are what .ci/run does from nothing, so here only its `.venv/bin/atm` steps run."""

from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import codec
from codec.files import read_image

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
MARK = re.compile(r"<!--\s*readme-test:(.*?)-->")
#: Times differ from run to run; every other figure must match.
DURATION = re.compile(r"\b\d+(\.\d+)? s\b")


@dataclass
class Block:
    lang: str
    lines: list[str]
    line: int  # where it starts in README.md (for messages)
    mark: str | None  # the readme-test comment before it, if any


def blocks(text: str) -> list[Block]:
    found, mark, current = [], None, None
    for number, line in enumerate(text.splitlines(), 1):
        if current is not None:
            if line.startswith("```"):
                found.append(current)
                current = None
            else:
                current.lines.append(line)
        elif line.startswith("```"):
            current = Block(line[3:].strip(), [], number, mark)
            mark = None
        elif MARK.search(line):
            mark = MARK.search(line).group(1).strip()
        elif line.strip():
            mark = None
    return found


def commands(block: Block) -> list[tuple[str, list[str] | None]]:
    """(command, expected output lines or None when the README shows none to check)."""
    if block.mark:
        # the fresh-machine block: its atm steps, without the venv, pip and pytest ones
        steps = [p.strip() for line in block.lines if not line.startswith("#") for p in line.split("&&")]
        return [(p.removeprefix(".venv/bin/"), None) for p in steps if p.startswith(".venv/bin/atm ")]
    if block.lang == "sh":
        return [(line, None) for line in block.lines if line.strip() and not line.lstrip().startswith("#")]
    steps = []
    for line in block.lines:
        if line.startswith("$ "):
            steps.append((line[2:], []))
        else:
            steps[-1][1].append(line)
    return steps


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> tuple[Path, dict]:
    """A scratch copy of what the README's commands read, and `atm` on the PATH."""
    work = tmp_path_factory.mktemp("readme")
    shutil.copytree(ROOT / "examples", work / "examples")
    # the tour's folder of scans: four images and a file that is not one
    (work / "scans").mkdir()
    for name in "abcd":
        shutil.copy(ROOT / "examples" / "range_scene.png", work / "scans" / f"{name}.png")
    (work / "scans" / "bad.png").write_bytes(b"not a PNG")
    bin_dir = work / ".bin"
    bin_dir.mkdir()
    wrapper = bin_dir / "atm"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m codec "$@"\n')
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}", PYTHONPATH=str(ROOT))
    return work, env


def test_only_the_fresh_machine_commands_are_left_to_ci():
    marked = [b for b in blocks(README.read_text()) if b.mark]
    assert len(marked) == 1, [b.line for b in marked]
    text = "\n".join(marked[0].lines)
    assert "pip install" in text and "pytest" in text
    # command 1 installs, then round-trips the example: those three atm steps run here
    assert [c.split()[:2] for c, _ in commands(marked[0])] == [["atm", "encode"], ["atm", "decode"], ["atm", "info"]]


@dataclass
class Run:
    where: str
    expected: list[str] | None
    status: int
    printed: str


@pytest.fixture(scope="module")
def runs(workdir) -> list[Run]:
    """Every command of the README's unmarked sh and console blocks, run in order."""
    work, env = workdir
    done = []
    for block in blocks(README.read_text()):
        if block.lang not in ("sh", "console"):
            continue
        for command, expected in commands(block):
            r = subprocess.run(
                ["bash", "-c", command], cwd=work, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL, text=True,
            )
            done.append(Run(f"README.md block at line {block.line}: {command}", expected, r.returncode, r.stdout))
    return done


def test_every_readme_command_runs_and_prints_what_the_readme_shows(runs):
    assert len(runs) >= 12  # the README shows twelve today: a parser that finds none must fail
    for run in runs:
        if run.expected is None:
            assert run.status == 0, f"{run.where}\n{run.printed}"
            continue
        failed = any(line.startswith("atm: error:") for line in run.expected)
        assert (run.status != 0) == failed, f"{run.where}\n{run.printed}"
        printed = run.printed.rstrip("\n").splitlines()
        assert [DURATION.sub("… s", x) for x in printed] == [DURATION.sub("… s", x) for x in run.expected], (
            f"{run.where}: the README shows other output than the command prints; it prints:\n{run.printed}"
        )


def test_the_tour_leaves_the_tracked_picture_alone_and_it_is_current(workdir, runs):
    """The tour draws the mesh into the working folder (not docs/), and docs/mesh.png is
    what that command draws today (regenerate it with the tour's two commands)."""
    work, _ = workdir
    tour = [b for b in blocks(README.read_text()) if any("atm mesh" in line for line in b.lines)]
    assert tour and not any("docs/" in line for b in tour for line in b.lines if line.startswith("atm"))
    drawn = work / "mesh.png"
    assert drawn.exists(), "the tour's atm mesh command drew nothing"
    assert np.array_equal(read_image(drawn), read_image(ROOT / "docs" / "mesh.png")), (
        "docs/mesh.png is stale: run the tour's atm encode and atm mesh commands and copy mesh.png to docs/"
    )


def test_every_readme_python_block_runs(workdir, runs, monkeypatch):
    """The Python blocks run too, in order, after the commands (the Pillow block opens the
    tour's scene.atm), with the arrays they name made here."""
    from tests.synthetic import range_scene

    work, _ = workdir
    monkeypatch.chdir(work)
    image = range_scene(120, 90, seed=5)
    dem = range_scene(120, 90, seed=6).astype(np.float32)
    dem[:10, :10] = -9999
    names = {
        "image": image,
        "depth_m": range_scene(120, 90, seed=7).astype(np.float32) / 50,
        "dem": dem,
        "array": np.empty_like(image),
        "width": 120,
        "height": 90,
        "source": np.array_split(image, 4),
        "sink": np.empty_like(image),
    }
    python = [b for b in blocks(README.read_text()) if b.lang == "python"]
    assert len(python) >= 3
    for block in python:
        exec(compile("\n".join(block.lines), f"README.md block at line {block.line}", "exec"), names)
    assert np.array_equal(names["sink"], codec.read("big.atm"))
    assert np.array_equal(names["array"], codec.decode(names["data"]))

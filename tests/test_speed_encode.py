"""benchmarks/speed.py's encode tables: equal vertex count (also resized), equal max
error with bytes and vertex counts, and the quality encode against a peer."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _table(text: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in text.splitlines() if line.startswith("|")]


def test_speed_benchmark_prints_its_encode_tables() -> None:
    pytest.importorskip("pydelatin")
    run = subprocess.run(
        [sys.executable, "benchmarks/speed.py", "--no-decode", "--images", "text", "--encode-repeat", "1",
         "--encode-sides", "64", "--dem-size", "32", "--max-errors", "20", "--quality", "40"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    budget, bound, quality = (_table(t) for t in run.stdout.strip().split("\n\n"))
    assert [r[:2] for r in budget[2:]] == [["text", "448x172"], ["text", "64x64"]]
    assert all(float(r[-1]) > 0 for r in budget[2:])
    # a row for the encode a user calls and one for the mesh alone, each E
    head, _, *rows = bound
    assert head[2:6] == ["atm encode", "atm bytes", "atm vertices", "delatin vertices"]
    assert [r[:3] for r in rows] == [["32x32", "20", "default"], ["32x32", "20", "mesh only"]]
    assert head[-1] == "CPU atm / delatin"
    assert all(int(r[3].replace(",", "")) > 0 and float(r[-1]) > 0 for r in rows)
    head, _, row = quality
    assert head[2] == "atm quality=40 ms" and row[0] == "text" and float(row[-1]) > 0

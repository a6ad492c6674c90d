"""Smoke runs of the benchmark scripts that need nothing beyond the test extra: they
must keep running and print their table (their figures are measurements, not checked)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _table(stdout: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip().strip("|").split("|")]
            for line in stdout.splitlines() if line.startswith("|")]


def test_speed_benchmark_prints_its_table() -> None:
    run = subprocess.run(
        [sys.executable, "benchmarks/speed.py", "--repeat", "1", "--images", "text",
         "--encode-repeat", "1", "--dem-size", "32", "--max-errors", "20"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    tables = run.stdout.split("\n\n")
    head, rule, *rows = _table(tables[0])
    assert [r[0] for r in rows] == ["text"]
    row = rows[0]
    assert len(row) == len(head) == len(rule)
    assert row[1] == "448x172"
    figures = dict(zip(head[3:], map(float, row[3:])))
    assert {"jpeg ms", "render ms", "decode ms", "triangulate ms", "render / jpeg"} <= figures.keys()
    assert {"png ms", "decode / jpeg", "decode / png"} <= figures.keys()
    assert all(f > 0 for f in figures.values())
    # the thread scaling: one row, a positive throughput ratio
    head, rule, row = _table(tables[1])
    assert head[-1] == "two threads / one thread throughput" and float(row[-1]) > 0


def test_canonical_benchmark_prints_its_tables() -> None:
    run = subprocess.run(
        [sys.executable, "benchmarks/canonical.py", "--images", "text", "--timed", "text", "--repeat", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, rule, text, total, head2, rule2, timed = _table(run.stdout)
    assert text[0] == "text" and total[0] == "all" and timed[0] == "text"
    figures = dict(zip(head[1:], (float(f.replace(",", "")) for f in text[1:])))
    assert figures["free edges"] > 0 and 0 < figures["uniform ties %"] < 100
    assert abs(figures["change %"]) < 5
    assert float(timed[3]) > 0

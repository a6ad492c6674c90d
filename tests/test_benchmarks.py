"""Smoke runs of the benchmark scripts: they must keep running and print their table
(their figures are measurements, not checked). Those that need the bench extra skip
without it."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

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
    assert {"png ms", "decode / jpeg", "decode / png", "decoder ms", "decoder / jpeg", "decoder / png"} <= figures.keys()
    assert all(f > 0 for f in figures.values())
    # the thread scaling: one row, a positive throughput ratio
    head, rule, *rows = _table(tables[1])
    assert [r[0] for r in rows] == ["codec.decode", "a Decoder per thread"]
    assert head[-1] == "two threads / one thread throughput" and all(float(r[-1]) > 0 for r in rows)


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


def test_range_benchmark_quick_run_meets_its_own_bounds(tmp_path: Path) -> None:
    """benchmarks/range.py on a crop of the corpus disparity map: every row present, the
    quantiser peer within its bound (it holds by construction) and every lossless peer
    exact, so a broken error measurement or hole check shows here."""
    pytest.importorskip("imagecodecs")
    pytest.importorskip("tifffile")
    pytest.importorskip("matplotlib")
    run = subprocess.run(
        [sys.executable, "benchmarks/range.py", "--quick", "--repeat", "1",
         "--images", "motorcycle_disp", "--errors", "0.5", "2", "--plot", str(tmp_path / "range.png")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    bounded, times, lossless = (_table(t) for t in run.stdout.split("## ")[1:])
    head, _, *rows = bounded
    assert [r[1].split(" %")[0] for r in rows] == ["0.5", "2"]
    for row in rows:
        cells = dict(zip(head, row))
        bound = float(cells["E"].split("= ")[1])
        size, err = cells["q2E+jxl (err)"].replace(",", "").rstrip(")").split(" (")
        assert int(size) > 0 and float(err) <= bound
        assert "!" not in cells["q2E+jxl (err)"]
    assert len(times) == 2 + len(rows)
    head, _, row = lossless
    cells = dict(zip(head, row))
    for peer in ("png", "jpegls", "jxl"):
        assert cells[f"{peer} bytes (err)"].endswith("(0)")
    assert (tmp_path / "range.png").stat().st_size > 0


def test_range_benchmark_lossless_float_table(tmp_path: Path) -> None:
    """benchmarks/range.py's float lossless table on a crop of the DEM resampled with NaN
    holes: .atm and the bit-exact peers marked lossless, ratios given."""
    pytest.importorskip("imagecodecs")
    pytest.importorskip("tifffile")
    from tests.test_geotiff import shared_file

    shared_file("srtm_dem.tif")
    run = subprocess.run(
        [sys.executable, "benchmarks/range.py", "--quick", "--repeat", "1", "--images", "srtm_f32_holes", "--errors",
         "--plot", str(tmp_path / "range.png")],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    table = next(t for t in run.stdout.split("## ")[1:] if t.startswith("Lossless float"))
    head, _, row = _table(table)
    cells = dict(zip(head, row))
    assert cells["atm lossless"] == "lossless"
    for codec_name in ("atm", "jxl", "zstd+fpred", "deflate+fpred"):
        assert cells[f"{codec_name} bytes (err)"].endswith("(0)")
    assert float(cells["atm / zstd+fpred"]) > 0


def _bench(name: str = "range_study"):
    """A module of benchmarks/ (they import each other by their plain names)."""
    import importlib

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_study_code_length_is_the_sequential_adaptive_one() -> None:
    """range_study.adaptive_bits (vectorised) equals the code length of adaptive counts
    updated symbol by symbol, as an arithmetic coder would."""
    study = _bench()
    rng = np.random.default_rng(3)
    ctx = rng.integers(0, 4, 500)
    sym = np.minimum(rng.geometric(0.4, 500) - 1, 5) * (ctx % 2) + rng.integers(0, 2, 500)
    alphabet = int(sym.max()) + 1
    counts = np.zeros((4, alphabet))
    bits = 0.0
    for c, s in zip(ctx, sym):
        bits -= np.log2((counts[c, s] + study.KT) / (counts[c].sum() + study.KT * alphabet))
        counts[c, s] += 1
    assert study.adaptive_bits(ctx, sym, alphabet) == pytest.approx(bits, rel=1e-12)


def test_study_cover_quantiser_keeps_the_bound_with_fewest_levels() -> None:
    """Sparse values (a sensor's depth steps) get one level per cluster and every value
    lies within E of its level's middle; dense values get the uniform step 2E + 1."""
    study = _bench()
    values = np.array([100, 101, 103, 140, 141, 300, 5000, 5003, 5004], dtype=np.float64)
    starts, index = study.cover_quantiser(values, 2.5, integer=True)
    assert starts.tolist() == [100, 140, 300, 5000]
    assert np.abs(starts[index] + 2 - values).max() <= 2
    dense = np.arange(0, 1000, dtype=np.float64)
    starts, index = study.cover_quantiser(dense, 3.0, integer=True)
    assert np.all(np.diff(starts) == 7) and np.abs(starts[index] + 3 - dense).max() <= 3


def test_study_quick_run_prints_every_variant() -> None:
    """range_study.py --quick on the disparity crop: one row, every variant a ratio."""
    pytest.importorskip("imagecodecs")
    study = _bench()
    run = subprocess.run(
        [sys.executable, "benchmarks/range_study.py", "--quick", "--images", "motorcycle_disp",
         "--errors", "2", "--densities", "0.01"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, _, row = _table(run.stdout)
    cells = dict(zip(head, row))
    assert all(float(cells[f"{v} ÷ peer"]) > 0 for v in study.VARIANTS)


def test_range_coder_round_trips_at_the_estimated_length() -> None:
    """benchmarks/range_coder.py gives its symbols back, in about the bytes the study's
    adaptive estimate says (the estimate's claim to be reachable rests on this)."""
    study = _bench()
    range_coder = _bench("range_coder")
    rng = np.random.default_rng(7)
    ctx = rng.integers(0, 6, 20000)
    sym = np.minimum(rng.geometric(0.25 + 0.1 * ctx) - 1, 11)
    scale = round(1 / study.KT)

    def models() -> dict:
        return {c: range_coder.Model(12, scale) for c in range(6)}

    data = range_coder.encode(zip(ctx.tolist(), sym.tolist()), models())
    assert list(range_coder.decode(data, ctx.tolist(), models())) == sym.tolist()
    estimate = study.adaptive_bits(ctx, sym, 12) / 8
    assert estimate <= len(data) <= estimate * 1.01 + 8


def test_mesh_formats_benchmark_quick_run() -> None:
    """benchmarks/mesh_formats.py: .atm against Draco and quantized-mesh on one mesh."""
    for name in ("DracoPy", "quantized_mesh_encoder", "pydelatin"):
        pytest.importorskip(name)
    run = subprocess.run(
        [sys.executable, "benchmarks/mesh_formats.py", "--quick", "--errors", "5"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, rule, row = _table(run.stdout)
    assert row[:3] == ["synthetic", "96x80", "5"]
    figures = dict(zip(head[3:], (float(f.replace(",", "")) for f in row[3:])))
    assert figures["vertices"] > 0 and figures["atm bytes"] > 0
    assert figures["draco / atm"] > 0 and figures["qm.gz / atm"] > 0


def test_study_value_domain_predictors_keep_the_bound() -> None:
    """The interpolation predictor reconstructs within E on integer and float data
    with holes (it checks itself and raises), and the mesh-residual quantiser's
    reconstruction mesh + q x step is within E."""
    study = _bench()
    bench = _bench("range")
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:37, 0:53]
    smooth = 1000 + 7 * xx + 3 * yy + rng.integers(-20, 20, xx.shape)
    smooth[5:9, 10:30] = 0
    for image, nodata in ((smooth.astype(np.uint16), 0), (smooth.astype(np.float32) / 7, None)):
        case = bench.Case("t", image, nodata)
        for e in (0.0, 1.5, 12.0) if case.integer else (0.3, 4.0):
            assert study.interpolation_bytes(case, e) > 0
            step = bench.quantiser_step(case, e)
            guess = image.astype(np.float64) + rng.normal(0, 30, image.shape).round()
            d = image - guess
            q = study.quantise_around(d, e, step, case.integer)
            assert np.abs(guess + q * step - image).max() <= (np.floor(e) if case.integer else e) + 1e-4


def test_slack_benchmark_prints_its_table() -> None:
    run = subprocess.run(
        [sys.executable, "benchmarks/slack.py", "--data", "dem64", "--multiples", "0.5", "3"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, rule, *rows = _table(run.stdout)
    assert len(head) == len(rule) == 11 and [r[0] for r in rows] == ["dem64", "dem64"]
    # below the threshold the rule keeps every level exact; well above it, it gives slack
    assert [r[8] for r in rows] == ["0", "1"]
    assert all(int(r[3].replace(",", "")) > 0 and int(r[5].replace(",", "")) > 0 for r in rows)


def test_speed_benchmark_in_cpu_time() -> None:
    """--cpu: the decode table in CPU milliseconds, the thread table with each run's CPU
    time and the cores it used (one thread at most one core, two at most two)."""
    run = subprocess.run(
        [sys.executable, "benchmarks/speed.py", "--repeat", "1", "--images", "text", "--no-encode", "--cpu"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    tables = run.stdout.split("\n\n")
    head, _, row = _table(tables[0])
    figures = dict(zip(head[3:], map(float, row[3:])))
    assert {"jpeg CPU ms", "decode CPU ms", "decode / jpeg", "decode / png"} <= figures.keys()
    assert all(f > 0 for f in figures.values())
    head, _, *rows = _table(tables[1])
    assert len(rows) == 2  # codec.decode, and a Decoder per thread
    for row in rows:
        figures = dict(zip(head, row))
        assert 0 < float(figures["one thread CPU ms"]) and 0 < float(figures["two threads CPU ms"])
        assert 0 < float(figures["cores used by one thread"]) <= 1.05
        assert 0 < float(figures["cores used by two threads"]) <= 2.1
        assert float(figures["cores used two / one"]) > 0


def test_glue_benchmark_prints_its_table(tmp_path) -> None:
    """benchmarks/glue.py: per-decode times of each file, the glue the decode less its
    two kernels (so below the decode and above zero)."""
    run = subprocess.run(
        [sys.executable, "benchmarks/glue.py", "--rounds", "1", "--decodes", "1", "--files", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, _, *rows = _table(run.stdout)
    assert [r[0] for r in rows][:4] == ["camera", "moon", "astronaut", "camera_bands32"]
    for row in rows:
        figures = dict(zip(head, row))
        decode, glue = float(figures["this checkout (codec.decode): decode us"]), float(figures["glue us"])
        assert 0 < glue < decode


def test_glue_benchmark_times_a_decoder(tmp_path) -> None:
    """glue.py --decoder: the worker decodes with one codec.Decoder, and says so."""
    run = subprocess.run(
        [sys.executable, "benchmarks/glue.py", "--rounds", "1", "--decodes", "1", "--files", str(tmp_path),
         "--decoder"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, _, *rows = _table(run.stdout)
    assert "this checkout (codec.Decoder): decode us" in head
    for row in rows:
        figures = dict(zip(head, row))
        assert 0 < float(figures["glue us"]) < float(figures["this checkout (codec.Decoder): decode us"])


def test_speed_thread_table_gives_each_thread_its_own_files() -> None:
    """The threads criterion as stated: in the two-thread run each worker decodes its
    own list, whole and alone; in the one-thread run one thread decodes both lists."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import speed
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    lists = [[b"a%d" % i for i in range(5)], [b"b%d" % i for i in range(5)]]
    seen: list[tuple[int, bytes]] = []
    lock = threading.Lock()

    def decoder():
        def decode(data: bytes) -> None:
            with lock:
                seen.append((threading.get_ident(), data))
        return decode

    head, row = speed._thread_row(lists, 1, True, "probe", decoder)
    assert row[:2] == ["probe", "10"]
    # a warm-up decode by the second worker, then warm-up and one round of each run
    runs = [seen[1 + 10 * k: 11 + 10 * k] for k in range(4)]
    for one, two in (runs[0:2], runs[2:4]):
        assert len({t for t, _ in one}) == 1 and [d for _, d in one] == lists[0] + lists[1]
        by_thread: dict[int, list[bytes]] = {}
        for t, d in two:
            by_thread.setdefault(t, []).append(d)
        assert sorted(by_thread.values()) == lists
    assert len(seen) == 41
    figures = dict(zip(head, row))
    if Path("/proc/stat").exists():  # other processes' load, and the rounds free of it
        assert figures["quiet rounds"] in ("0 of 1", "1 of 1")
        assert (figures["throughput in quiet rounds"] == "-") == (figures["quiet rounds"] == "0 of 1")
    if Path("/proc/thread-self/schedstat").exists():  # each thread's own time, from the kernel
        assert float(figures["throughput less run-queue waits"]) > 0


def test_speed_thread_lists_are_files_of_their_own() -> None:
    """Each decode of the threads table reads a buffer no other decode reads: two
    threads never decode the same file object, as no two requests to a server do."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import speed
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    files = [b"camera", b"moon", b"astronaut"]
    lists = speed.thread_lists(files, least=10)
    assert [len(k) for k in lists] == [12, 12]
    assert lists[0][:4] == [b"camera", b"moon", b"astronaut", b"camera"]
    assert lists[1][:4] == [b"moon", b"astronaut", b"camera", b"moon"]
    every = lists[0] + lists[1]
    assert len({id(data) for data in every}) == len(every)
    assert not any(data is f for data in every for f in files)


def test_glue_benchmark_gives_the_field_passes_and_page_faults(tmp_path) -> None:
    """glue.py's columns for the decode's budget: the MESH field passes' part of the
    glue (band_front and band_values) and the minor page faults a decode takes."""
    run = subprocess.run(
        [sys.executable, "benchmarks/glue.py", "--rounds", "1", "--decodes", "2", "--files", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stderr
    head, _, *rows = _table(run.stdout)
    for row in rows:
        figures = dict(zip(head, row))
        assert 0 < float(figures["of it field passes us"]) < float(figures["glue us"])
        paged = figures["page faults"]
        assert paged == "-" if not sys.platform.startswith("linux") else float(paged) >= 0

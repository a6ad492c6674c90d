"""`atm encode/decode` on many files, progress on a terminal, and `atm compare`."""

from __future__ import annotations

import json

import numpy as np
import pytest

import codec
from codec.files import read_image, write_image
from tests.synthetic import range_scene
from tests.terminal import run_on_a_terminal
from tests.test_cli import atm


@pytest.fixture()
def folder(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    write_image(src / "a.png", range_scene(48, 32, seed=1))
    write_image(src / "b.pgm", range_scene(40, 30, seed=2, dtype=np.uint16))
    write_image(src / "c.png", np.stack([range_scene(30, 20, seed=s) for s in (3, 4, 5)], -1))
    (src / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n but not really")
    (src / "notes.txt").write_text("not an image, not picked up from a directory")
    return src


def test_directory_converts_with_a_failing_file_named(folder, tmp_path):
    out = tmp_path / "out" / "deeper"  # created, parents too
    r = atm("encode", folder, out, "--points", 200, "--jobs", 2)
    err = r.stderr.decode()
    assert r.returncode == 1
    assert sorted(p.name for p in out.iterdir()) == ["a.atm", "b.atm", "c.atm"]
    assert "broken.png" in err.splitlines()[-1] and "1 of 4 file(s) failed" in err
    assert "encoded 3 of 4 file(s)" in err and "bytes in" in err
    assert "\r" not in err  # not a terminal: no progress bar
    for name, src in (("a", "a.png"), ("b", "b.pgm"), ("c", "c.png")):
        decoded = codec.read(out / f"{name}.atm")
        original = read_image(folder / src)
        assert decoded.shape == original.shape and decoded.dtype == original.dtype
    # and back: a glob of .atm files, decoded into another directory, all succeed
    back = tmp_path / "back"
    r = atm("decode", str(out / "*.atm"), back, "--format", "tif", "--quiet")
    assert r.returncode == 0 and r.stderr == b""
    assert sorted(p.name for p in back.iterdir()) == ["a.tif", "b.tif", "c.tif"]
    np.testing.assert_array_equal(read_image(back / "b.tif"), codec.read(out / "b.atm"))


def test_several_files_and_one_job(folder, tmp_path):
    r = atm("encode", folder / "a.png", folder / "c.png", tmp_path / "o", "-j", 1)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["a.atm", "c.atm"]


def test_batch_usage_errors(folder, tmp_path):
    (tmp_path / "file").write_bytes(b"x")
    r = atm("encode", folder, tmp_path / "file")
    assert r.returncode == 2 and b"is a file" in r.stderr
    r = atm("encode", str(tmp_path / "nothing*.png"), tmp_path / "o")
    assert r.returncode == 1 and b"no images" in r.stderr
    write_image(tmp_path / "a.tif", range_scene(8, 8))
    r = atm("encode", folder / "a.png", tmp_path / "a.tif", tmp_path / "o")
    assert r.returncode == 1 and b"would both be written" in r.stderr
    assert not (tmp_path / "o").exists()


def _on_a_terminal(*args) -> tuple[int, bytes]:
    """Run atm with its standard error on a pseudo-terminal; return (status, stderr)."""
    status, err, _ = run_on_a_terminal(*args)
    return status, err


def test_progress_bar_on_a_terminal_only(folder, tmp_path):
    status, err = _on_a_terminal("encode", folder, tmp_path / "o", "--points", 100)
    assert status == 1 and b"\r[" in err and b"100%" in err
    status, err = _on_a_terminal("encode", folder, tmp_path / "q", "--points", 100, "--quiet")
    assert status == 1 and b"\r[" not in err and b"broken.png" in err


def test_long_single_encode_shows_band_progress(tmp_path):
    write_image(tmp_path / "tall.png", range_scene(40, 90, seed=6))
    status, err = _on_a_terminal("encode", tmp_path / "tall.png", tmp_path / "t.atm", "--band-height", 20)
    assert status == 0
    assert b"21/90 rows" in err and b"90/90 rows" in err
    plain = atm("encode", tmp_path / "tall.png", "-", "--band-height", 20)
    assert plain.stderr == b"" and plain.stdout == (tmp_path / "t.atm").read_bytes()


def test_compare_any_formats(tmp_path):
    image = range_scene(50, 40, seed=7)
    write_image(tmp_path / "a.png", image)
    codec.write(tmp_path / "a.atm", image, points=300)
    r = atm("compare", tmp_path / "a.png", tmp_path / "a.atm", "--json")
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    err = codec.read(tmp_path / "a.atm").astype(float) - image
    assert got["rms"] == pytest.approx(np.sqrt(np.mean(err**2)))
    assert got["max_error"] == np.abs(err).max()
    assert got["psnr"] == pytest.approx(20 * np.log10(255 / got["rms"]))
    r = atm("compare", tmp_path / "a.png", tmp_path / "a.png")
    assert r.returncode == 0 and b"identical" in r.stdout
    write_image(tmp_path / "small.png", image[:10])
    r = atm("compare", tmp_path / "a.png", tmp_path / "small.png")
    assert r.returncode == 1
    assert r.stderr.decode().strip().splitlines() == [
        "atm: error: the images differ in shape: 50x40 gray uint8 against 50x10 gray uint8"
    ]


def test_compare_reports_colour_per_channel(tmp_path):
    a = np.zeros((4, 5, 3), np.uint8)
    b = a.copy()
    b[..., 1] = 10
    np.save(tmp_path / "a.npy", a)
    np.save(tmp_path / "b.npy", b)
    got = json.loads(atm("compare", tmp_path / "a.npy", tmp_path / "b.npy", "--json").stdout)
    assert [c["max_error"] for c in got["per_channel"]] == [0, 10, 0]
    assert got["per_channel"][0]["psnr"] is None and got["max_error"] == 10


def test_an_existing_directory_as_output_takes_a_single_file(folder, tmp_path):
    (tmp_path / "dir").mkdir()
    r = atm("encode", folder / "a.png", tmp_path / "dir", "--quiet")
    assert r.returncode == 0, r.stderr
    assert [p.name for p in (tmp_path / "dir").iterdir()] == ["a.atm"]


@pytest.mark.parametrize("command", ["mesh", "compare"])
def test_new_commands_have_help(command):
    r = atm(command, "--help")
    assert r.returncode == 0 and b"usage: atm " + command.encode() in r.stdout


def test_float_data_decodes_only_to_formats_that_keep_it(tmp_path):
    depth = np.linspace(0.5, 4.0, 12 * 10, dtype=np.float32).reshape(10, 12)
    codec.write(tmp_path / "d.atm", depth, max_error=0.01)
    r = atm("decode", tmp_path / "d.atm", tmp_path / "d.png")
    assert r.returncode == 1 and b"decode it to .tif or .npy" in r.stderr
    assert not (tmp_path / "d.png").exists()
    assert atm("decode", tmp_path / "d.atm", tmp_path / "d.npy").returncode == 0
    assert np.abs(np.load(tmp_path / "d.npy") - depth).max() <= 0.01 + 1e-6


def test_stopping_a_batch_leaves_no_executor_thread_to_race_the_exit():
    """Ctrl-C in a batch: _stop ends the workers mid-file, and the executor's manager
    thread must be gone when it returns. Left running, it closes its wake-up pipe while
    Python's exit handler writes to it, and `atm` printed a "Bad file descriptor"
    traceback after "atm: interrupted" (a flaky failure of the Ctrl-C test)."""
    import time
    from concurrent.futures import ProcessPoolExecutor

    from codec.cli import batch

    pool = ProcessPoolExecutor(2, initializer=batch._worker_setup)
    futures = [pool.submit(time.sleep, 60) for _ in range(3)]
    deadline = time.monotonic() + 20
    while not any(f.running() for f in futures) and time.monotonic() < deadline:
        time.sleep(0.01)
    manager = pool._executor_manager_thread
    started = time.monotonic()
    batch._stop(pool)
    assert time.monotonic() - started < 10
    assert not manager.is_alive()
    assert futures[-1].cancelled() or futures[-1].done()

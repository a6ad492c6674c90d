"""The `atm` command: round trips through files and pipes, one-line errors, no partial files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import codec
from codec.files import read_image, write_image
from tests.synthetic import range_scene

ROOT = Path(__file__).resolve().parent.parent


def atm(*args, stdin: bytes | None = None, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "codec", *map(str, args)], input=stdin, capture_output=True, cwd=cwd
    )


@pytest.fixture(scope="module")
def png(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "scene.png"
    write_image(path, range_scene(96, 64, seed=2))
    return path


def rms(a, b) -> float:
    return float(np.sqrt(np.mean((a.astype(float) - b.astype(float)) ** 2)))


def test_encode_decode_info(png, tmp_path):
    out_atm, out_png = tmp_path / "a.atm", tmp_path / "b.png"
    r = atm("encode", png, out_atm, "--points", 600)
    assert r.returncode == 0, r.stderr
    r = atm("decode", out_atm, out_png)
    assert r.returncode == 0, r.stderr
    assert rms(read_image(out_png), read_image(png)) < 20
    r = atm("info", out_atm, "--json")
    info = json.loads(r.stdout)
    assert (info["width"], info["height"]) == (96, 64)
    assert abs(info["vertices"] - 600) <= 60
    assert info["bytes"] == out_atm.stat().st_size and info["triangles"] > 0


def test_pipe_round_trip(png, tmp_path):
    enc = atm("encode", "-", "-", stdin=png.read_bytes())
    assert enc.returncode == 0, enc.stderr
    dec = atm("decode", "-", tmp_path / "out.png", stdin=enc.stdout)
    assert dec.returncode == 0, dec.stderr
    assert read_image(tmp_path / "out.png").shape == (64, 96)
    dec = atm("decode", "-", "-", "--format", "pgm", stdin=enc.stdout)
    assert dec.stdout.startswith(b"P5")


@pytest.mark.parametrize("ext", [".png", ".pgm", ".tif"])
def test_output_format_follows_the_extension(png, tmp_path, ext):
    atm("encode", png, tmp_path / "a.atm")
    assert atm("decode", tmp_path / "a.atm", tmp_path / f"b{ext}").returncode == 0
    assert read_image(tmp_path / f"b{ext}").shape == (64, 96)


def test_sixteen_bit_png_round_trips(tmp_path):
    src = tmp_path / "deep.png"
    write_image(src, range_scene(50, 40, seed=1, dtype=np.uint16))
    assert atm("encode", src, tmp_path / "d.atm").returncode == 0
    assert atm("decode", tmp_path / "d.atm", tmp_path / "d.png").returncode == 0
    assert read_image(tmp_path / "d.png").dtype == np.uint16


def test_bad_input_is_one_line_exit_1_and_no_output(tmp_path, png):
    junk = tmp_path / "junk.atm"
    junk.write_bytes(b"\x89ATM\r\n\x1a\n\x01\x00garbage")
    out = tmp_path / "out.png"
    r = atm("decode", junk, out)
    assert r.returncode == 1
    lines = r.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("atm: error: ")
    assert "Traceback" not in r.stderr.decode()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.atm"]


def test_failed_run_keeps_an_existing_output(tmp_path):
    out = tmp_path / "keep.png"
    out.write_bytes(b"precious")
    r = atm("decode", "-", out, stdin=b"not atm")
    assert r.returncode == 1
    assert out.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.png"]


def test_unreadable_image_and_missing_file(tmp_path):
    r = atm("encode", "-", tmp_path / "a.atm", stdin=b"hello")
    assert r.returncode == 1 and b"not an image" in r.stderr
    r = atm("encode", tmp_path / "missing.png", tmp_path / "a.atm")
    assert r.returncode == 1 and b"cannot read" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_bad_usage_exits_2():
    assert atm("encode").returncode == 2
    assert atm("frobnicate").returncode == 2


def test_unwritable_output_format(png, tmp_path):
    atm("encode", png, tmp_path / "a.atm")
    r = atm("decode", tmp_path / "a.atm", tmp_path / "b.jpg")
    assert r.returncode == 1 and b"cannot write .jpg" in r.stderr


@pytest.mark.parametrize("command", [[], ["encode"], ["decode"], ["info"]])
def test_help(command):
    r = atm(*command, "--help")
    assert r.returncode == 0 and b"usage: atm" in r.stdout


def test_debug_shows_the_traceback(tmp_path):
    r = atm("--debug", "decode", "-", tmp_path / "x.png", stdin=b"nope")
    assert r.returncode != 0 and b"Traceback" in r.stderr


def test_bundled_example_round_trips(tmp_path):
    example = ROOT / "examples" / "range_scene.png"
    assert atm("encode", example, tmp_path / "e.atm").returncode == 0
    assert atm("decode", tmp_path / "e.atm", tmp_path / "e.png").returncode == 0
    assert rms(read_image(tmp_path / "e.png"), read_image(example)) < 15


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_pgm_and_npy_stream_through_pipes(tmp_path, dtype):
    image = range_scene(70, 45, seed=9, dtype=dtype)
    pgm = tmp_path / "in.pgm"
    write_image(pgm, image)
    enc = atm("encode", "-", "-", "--band-height", "8", stdin=pgm.read_bytes())
    assert enc.returncode == 0, enc.stderr
    import codec

    assert codec.info(enc.stdout)["bands"] == 6
    dec = atm("decode", "-", "-", "--format", "pgm", stdin=enc.stdout)
    assert dec.returncode == 0, dec.stderr
    (tmp_path / "out.pgm").write_bytes(dec.stdout)
    out = read_image(tmp_path / "out.pgm")
    np.testing.assert_array_equal(out, codec.decode(enc.stdout))
    assert out.dtype == dtype
    # the same image as .npy, from a file (memory-mapped) and from a pipe
    npy = tmp_path / "in.npy"
    np.save(npy, image)
    from_file = atm("encode", npy, "-", "--band-height", "8")
    from_pipe = atm("encode", "-", "-", "--band-height", "8", stdin=npy.read_bytes())
    assert from_file.stdout == from_pipe.stdout == enc.stdout
    assert atm("decode", "-", tmp_path / "o.npy", stdin=enc.stdout).returncode == 0
    np.testing.assert_array_equal(np.load(tmp_path / "o.npy"), out)


def test_truncated_stream_is_an_error_and_leaves_no_file(tmp_path, png):
    data = atm("encode", png, "-", "--band-height", "8").stdout
    r = atm("decode", "-", tmp_path / "o.pgm", stdin=data[: len(data) - 30])
    assert r.returncode == 1 and b"ends" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_npy_of_unsupported_type_is_refused(tmp_path):
    np.save(tmp_path / "f.npy", np.zeros((4, 4), np.int64))
    r = atm("encode", tmp_path / "f.npy", tmp_path / "f.atm")
    assert r.returncode == 1 and b"int64" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.npy"]


def test_float_npy_with_holes_bounds_and_metadata(tmp_path):
    z = range_scene(60, 40, seed=2).astype(np.float32) * 0.1 + 300
    z[5:10, 5:10] = np.nan
    np.save(tmp_path / "dem.npy", z)
    r = atm("encode", tmp_path / "dem.npy", tmp_path / "dem.atm", "--max-error", "0.05",
            "--metadata", '{"units": "m"}')
    assert r.returncode == 0, r.stderr
    info = json.loads(atm("info", tmp_path / "dem.atm", "--json").stdout)
    assert info["metadata"] == {"units": "m"} and info["nodata"] == "NaN" and info["dtype"] == "float32"
    assert b"units" in atm("info", tmp_path / "dem.atm").stdout
    assert atm("decode", tmp_path / "dem.atm", tmp_path / "out.npy").returncode == 0
    out = np.load(tmp_path / "out.npy")
    assert np.isnan(out[5:10, 5:10]).all() and np.nanmax(np.abs(out - z)) <= 0.05
    # from a pipe the range must be given; without it the message says how
    r = atm("encode", "-", "-", stdin=(tmp_path / "dem.npy").read_bytes())
    assert r.returncode == 2 and b"--value-range" in r.stderr
    r = atm("encode", "-", "-", "--value-range", "300", "330", stdin=(tmp_path / "dem.npy").read_bytes())
    assert r.returncode == 0, r.stderr


def test_nodata_flag_and_bad_option_values(tmp_path, png):
    image = range_scene(50, 30, seed=3)
    image[3:8, 10:20] = 0
    write_image(tmp_path / "v.png", image)
    assert atm("encode", tmp_path / "v.png", tmp_path / "v.atm", "--nodata", "0").returncode == 0
    import codec

    out = codec.read(tmp_path / "v.atm")
    assert (out[3:8, 10:20] == 0).all()
    r = atm("encode", png, tmp_path / "x.atm", "--points", "0")
    assert r.returncode == 2 and b"points" in r.stderr
    r = atm("encode", png, tmp_path / "x.atm", "--quality", "200")
    assert r.returncode == 2 and b"quality" in r.stderr
    assert not (tmp_path / "x.atm").exists()


def test_effort_flag_matches_the_api(png, tmp_path):
    """--effort reaches the mesher: the file is the one codec.encode(effort=...) gives,
    and a level out of range is one line and exit status 2."""
    import codec

    out = tmp_path / "e.atm"
    r = atm("encode", png, out, "--points", 400, "--effort", 3)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == codec.encode(read_image(png), points=400, effort=3)
    assert out.read_bytes() != codec.encode(read_image(png), points=400)
    r = atm("encode", png, tmp_path / "bad.atm", "--effort", 9)
    assert r.returncode == 2 and r.stderr.decode().count("\n") == 1 and "effort" in r.stderr.decode()
    assert not (tmp_path / "bad.atm").exists()


def test_decode_backend_gl_gives_the_cpu_pixels(gl, png, tmp_path):
    data = tmp_path / "a.atm"
    assert atm("encode", png, data).returncode == 0
    for backend in ("cpu", "gl"):
        r = atm("decode", data, tmp_path / f"{backend}.png", "--backend", backend)
        assert r.returncode == 0, r.stderr
    assert np.array_equal(read_image(tmp_path / "gl.png"), read_image(tmp_path / "cpu.png"))


def test_decode_backend_gl_without_context_is_one_line(no_gl, png, tmp_path, capsys):
    from codec.cli.main import main

    data, out = tmp_path / "a.atm", tmp_path / "out.png"
    assert atm("encode", png, data).returncode == 0
    out.write_bytes(b"precious")
    assert main(["decode", str(data), str(out), "--backend", "gl"]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("atm: error: no headless OpenGL context")
    assert "libegl1" in lines[0] and "--backend cpu" in lines[0]
    assert out.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.atm", "out.png"]
    # an unknown backend is bad usage
    assert main(["decode", str(data), str(out), "--backend", "vulkan"]) == 2
    assert "choose one of cpu, gl" in capsys.readouterr().err


def test_max_rms_with_residual_layer(png, tmp_path):
    # issue #21: --residual takes --max-rms as well as --max-error
    out_atm, out_png = tmp_path / "r.atm", tmp_path / "r.png"
    r = atm("encode", png, out_atm, "--max-rms", "3", "--residual")
    assert r.returncode == 0, r.stderr
    assert atm("decode", out_atm, out_png).returncode == 0
    assert rms(read_image(out_png), read_image(png)) <= 3
    info = json.loads(atm("info", out_atm, "--json").stdout)
    # the layer's bound is widened from the first band's samples, streamed or not
    # (before, the CLI kept floor(max_rms) = 3 and only codec.encode widened it)
    assert info["residual"] > 3
    assert out_atm.read_bytes() == codec.encode(read_image(png), max_rms=3)


def test_bounds_give_the_same_file_from_the_cli_and_python(png, tmp_path):
    # issue #21: `atm encode --max-error E` = codec.encode(img, max_error=E), the residual
    # layer by default, --no-residual the mesh alone; `atm info` says which
    image = read_image(png)
    for flags, options, layered in (
        (["--max-error", "4"], dict(max_error=4), True),
        (["--max-rms", "2.5"], dict(max_rms=2.5), True),
        (["--max-error", "4", "--no-residual"], dict(max_error=4, residual=False), False),
    ):
        out = tmp_path / "b.atm"
        r = atm("encode", png, out, *flags, "--force")
        assert r.returncode == 0, r.stderr
        assert out.read_bytes() == codec.encode(image, **options)
        text = atm("info", out).stdout.decode()
        assert ("residual layer:" in text) == layered and ("mesh alone" in text) == (not layered), text

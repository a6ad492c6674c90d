"""`atm` follows the command-line conventions of cwebp, cjxl, avifenc, gzip and zstd:
-q is quality, -v verbose, -o the output, --version everywhere, no binary to a terminal."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest

import codec
from codec.cli.main import build_parser, main
from codec.files import write_image
from tests.synthetic import range_scene
from tests.terminal import run_on_a_terminal


@pytest.fixture(scope="module")
def png(tmp_path_factory):
    path = tmp_path_factory.mktemp("conv") / "scene.png"
    write_image(path, range_scene(48, 40, seed=3))
    return path


def test_q_is_quality_not_quiet(png, tmp_path):
    out = tmp_path / "q.atm"
    assert main(["encode", str(png), str(out), "-q", "60"]) == 0
    loose = tmp_path / "loose.atm"
    assert main(["encode", str(png), str(loose), "--quality", "20"]) == 0
    assert len(out.read_bytes()) > len(loose.read_bytes())
    assert not (tmp_path / "60").exists()


def test_o_names_the_output_anywhere(png, tmp_path):
    out = tmp_path / "o.atm"
    assert main(["encode", "-o", str(out), str(png), "--points", "80"]) == 0
    assert codec.info(out.read_bytes())["width"] == 48
    back = tmp_path / "back.png"
    assert main(["decode", str(out), "--output", str(back)]) == 0
    assert back.exists()
    obj = tmp_path / "m.obj"
    assert main(["mesh", str(out), "-o", str(obj)]) == 0
    assert obj.read_text().startswith(("#", "v"))
    # an option between IN and OUT leaves OUT where the user put it
    again = tmp_path / "again.atm"
    assert main(["encode", str(png), "--points", "80", str(again)]) == 0
    assert again.read_bytes() == out.read_bytes()


def test_a_missing_output_is_bad_usage(png, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["encode", str(png)])
    assert exc.value.code == 2
    assert "-o OUT" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["encode", str(png), "x.atm", "--frobnicate"])
    assert "--frobnicate" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["encode", "decode", "mesh", "compare", "info"])
def test_version_on_every_subcommand(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"atm {codec.__version__}"


def test_verbose_keeps_the_summary_and_decode_has_it(png, tmp_path, capsys):
    out = tmp_path / "v.atm"
    assert main(["encode", str(png), str(out), "-v", "--points", "80"]) == 0
    assert "vertices" in capsys.readouterr().err
    assert main(["decode", str(out), str(tmp_path / "v.png"), "-v"]) == 0
    assert "PNG" in capsys.readouterr().err


def test_conflicting_size_flags_are_named(png, tmp_path, capsys):
    assert main(["encode", str(png), str(tmp_path / "c.atm"), "--quality", "50", "--points", "100"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "atm: error: --points and --quality both set the size: give one of them"
    assert not (tmp_path / "c.atm").exists()
    # a bound is met by the residual layer: --points then sizes the mesh beside it,
    # unless the mesh must meet the bound alone
    assert main(["encode", str(png), str(tmp_path / "p.atm"), "--max-error", "4", "--points", "60"]) == 0
    assert codec.info((tmp_path / "p.atm").read_bytes())["vertices"] == 60
    capsys.readouterr()
    args = ["encode", str(png), str(tmp_path / "n.atm"), "--max-error", "4", "--points", "60", "--no-residual"]
    assert main(args) == 2
    assert capsys.readouterr().err.strip() == "atm: error: --points and --max-error both set the size: give one of them"
    assert not (tmp_path / "n.atm").exists()


def test_messages_speak_command_line(png, tmp_path, capsys):
    assert main(["encode", str(png), str(tmp_path / "m.atm"), "--metadata", "[1, 2]"]) == 2
    err = capsys.readouterr().err
    assert "--metadata" in err and "dict" not in err and "JSON object" in err
    data = tmp_path / "d.atm"
    assert main(["encode", str(png), str(data), "--points", "80"]) == 0
    assert main(["decode", str(data), str(tmp_path / "d.jpg")]) == 1
    err = capsys.readouterr().err
    assert ".npy" in err and ".png" in err and not (tmp_path / "d.jpg").exists()


def test_encode_help_reads_like_an_encoders(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["encode", "--help"])
    text = capsys.readouterr().out
    assert "-q Q, --quality Q" in text and "-o OUT, --output OUT" in text and "-v, --verbose" in text
    assert "\n  --quiet" in text and "--version" in text


def test_binary_to_a_terminal_is_refused_unless_forced(png, tmp_path):
    data = tmp_path / "t.atm"
    data.write_bytes(codec.encode(range_scene(48, 40, seed=3), points=80))
    status, seen, err = run_on_a_terminal("decode", data, "-", stream="stdout")
    assert status == 2 and seen == b""
    assert b"terminal" in err and b"--force" in err and err.count(b"\n") == 1
    status, seen, _ = run_on_a_terminal("encode", png, "-", stream="stdout")
    assert status == 2 and seen == b""
    status, seen, _ = run_on_a_terminal("decode", data, "-", "--force", "--format", "pgm", stream="stdout")
    assert status == 0 and seen.startswith(b"P5")
    # a pipe is not a terminal
    r = subprocess.run([sys.executable, "-m", "codec", "decode", str(data), "-", "--format", "npy"], capture_output=True)
    assert r.returncode == 0 and np.load(io.BytesIO(r.stdout)).shape == (40, 48)

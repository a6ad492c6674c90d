"""Pictures from cameras and the web (cli/pictures.py): EXIF orientation, alpha, gray+alpha
and multi-page files are read as a user expects, or refused naming the option to use."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import codec
from codec.cli.main import main
from codec.files import write_image


def _encode(tmp_path, source, *flags) -> np.ndarray:
    out = tmp_path / "out.atm"
    assert main(["encode", str(source), str(out), "-q", "100", *flags]) == 0
    return codec.read(out)


def _rotated_jpeg(tmp_path):
    """A camera JPEG stored 20 wide and 12 tall with EXIF orientation 6 (rotate 90
    clockwise), so it is shown 12 x 20; the stored left half is bright: shown, the top half."""
    pixels = np.zeros((12, 20), np.uint8)
    pixels[:, :10] = 200
    exif = Image.Exif()
    exif[0x0112] = 6
    path = tmp_path / "camera.jpg"
    Image.fromarray(pixels).save(path, exif=exif, quality=100)
    return path


def test_exif_orientation_is_applied(tmp_path):
    # 20 wide, 12 tall as stored; orientation 6 (rotate 90 clockwise) shows it 12 x 20
    path = _rotated_jpeg(tmp_path)
    image = _encode(tmp_path, path)
    assert image.shape == (20, 12)
    assert image[:8].mean() > 150 and image[-8:].mean() < 50


def test_compare_reads_the_picture_upright(tmp_path, capsys):
    # atm compare of a rotated camera JPEG and the lossless .atm made from it: equal
    path = _rotated_jpeg(tmp_path)
    _encode(tmp_path, path)
    capsys.readouterr()
    assert main(["compare", "--json", str(path), str(tmp_path / "out.atm")]) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["width"], result["height"], result["max_error"]) == (12, 20, 0.0)


@pytest.mark.parametrize("mode, kind", [("RGBA", "RGBA"), ("LA", "gray+alpha")])
def test_alpha_is_refused_naming_the_option(tmp_path, capsys, mode, kind):
    path = tmp_path / "web.png"
    Image.new(mode, (8, 6)).save(path)
    assert main(["encode", str(path), str(tmp_path / "x.atm")]) == 1
    err = capsys.readouterr().err
    assert f"is {kind}" in err and "--alpha drop" in err and "--alpha white" in err and "4 channels" not in err
    assert not (tmp_path / "x.atm").exists()


def test_alpha_dropped_or_flattened(tmp_path):
    rgba = np.zeros((6, 8, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 100, 0  # red 100, fully transparent
    rgba[:, 4:, 3] = 255  # the right half opaque
    path = tmp_path / "web.png"
    Image.fromarray(rgba, "RGBA").save(path)
    dropped = _encode(tmp_path, path, "--alpha", "drop")
    assert dropped.shape == (6, 8, 3) and (dropped[..., 0] == 100).all()
    white = _encode(tmp_path, path, "--alpha", "white")
    assert (white[:, :4] == 255).all() and (white[:, 4:] == [100, 0, 0]).all()
    gray = tmp_path / "gray.png"
    Image.fromarray(rgba[..., [0, 3]], "LA").save(gray)
    black = _encode(tmp_path, gray, "--alpha", "black")
    assert black.shape == (6, 8) and (black[:, :4] == 0).all() and (black[:, 4:] == 100).all()


def test_multi_page_tiff_is_refused_or_a_page_chosen(tmp_path, capsys):
    pages = [Image.fromarray(np.full((10, 14), v, np.uint8)) for v in (10, 120, 240)]
    path = tmp_path / "stack.tif"
    pages[0].save(path, save_all=True, append_images=pages[1:])
    assert main(["encode", str(path), str(tmp_path / "x.atm")]) == 1
    err = capsys.readouterr().err
    assert "3 pages" in err and "--page N" in err and "0..2" in err
    assert (_encode(tmp_path, path, "--page", "1") == 120).all()
    assert main(["encode", str(path), str(tmp_path / "x.atm"), "--page", "3"]) == 2
    assert "numbered 0..2" in capsys.readouterr().err


def test_single_page_files_are_read_as_before(tmp_path, capsys):
    pixels = (np.arange(12 * 9).reshape(9, 12) * 500).astype(np.uint16)
    path = tmp_path / "depth.png"
    Image.fromarray(pixels).save(path)
    assert np.array_equal(_encode(tmp_path, path), pixels)
    # 16-bit colour PNG: Pillow would cut it to 8 bits, so OpenCV reads it
    colour = np.stack([pixels, pixels // 2, 65535 - pixels], axis=2)
    write_image(tmp_path / "rgb16.png", colour)
    assert np.array_equal(_encode(tmp_path, tmp_path / "rgb16.png"), colour)
    tif = tmp_path / "one.tif"
    Image.fromarray(pixels).save(tif)
    assert np.array_equal(_encode(tmp_path, tif), pixels)
    pgm = tmp_path / "x.pgm"
    pgm.write_bytes(b"P5\n2 1\n255\n\x01\x02")
    assert main(["encode", str(pgm), str(tmp_path / "p.atm"), "--page", "0"]) == 2
    assert "--page" in capsys.readouterr().err


def test_a_picture_on_standard_input_is_read_upright(tmp_path):
    import subprocess
    import sys

    path = _rotated_jpeg(tmp_path)
    out = tmp_path / "piped.atm"
    with open(path, "rb") as f:
        r = subprocess.run([sys.executable, "-m", "codec", "encode", "-", str(out), "-q", "100"], stdin=f, capture_output=True)
    assert r.returncode == 0, r.stderr
    assert codec.read(out).shape == (20, 12)

"""The Pillow plugin: Image.open / Image.save of .atm, lazy decoding, options, imageio."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import codec
import codec.stream
import codec.pil  # noqa: F401  (registers the plugin)
from tests.synthetic import range_scene

KINDS = [
    ("L", range_scene(40, 30, seed=1)),
    ("I;16", range_scene(40, 30, seed=2, dtype=np.uint16)),
    ("RGB", np.stack([range_scene(40, 30, seed=s) for s in (3, 4, 5)], -1)),
]


@pytest.mark.parametrize("mode, image", KINDS, ids=[k[0] for k in KINDS])
def test_open_gives_the_mode_and_the_codecs_pixels(tmp_path, mode, image):
    path = tmp_path / "x.atm"
    codec.write(path, image, points=300)
    with Image.open(path) as im:
        assert im.format == "ATM" and im.mode == mode and im.size == (40, 30)
        np.testing.assert_array_equal(np.asarray(im), codec.read(path))


@pytest.mark.parametrize("mode, image", KINDS, ids=[k[0] for k in KINDS])
def test_save_round_trips_through_pillow(tmp_path, mode, image):
    src = Image.fromarray(image)
    assert src.mode == mode
    path = tmp_path / "y.atm"
    src.save(path, quality=100)  # lossless
    assert path.read_bytes().startswith(codec.pil.SIGNATURE)
    with Image.open(path) as im:
        np.testing.assert_array_equal(np.asarray(im), image)


def test_save_passes_options_and_refuses_unknown_ones(tmp_path):
    im = Image.fromarray(range_scene(64, 48, seed=6))
    few, many = tmp_path / "few.atm", tmp_path / "many.atm"
    im.save(few, points=50, mesher="uniform")
    im.save(many, points=1500, mesher="uniform")
    assert codec.info(few.read_bytes())["vertices"] < codec.info(many.read_bytes())["vertices"]
    with pytest.raises(codec.OptionError, match="frobnicate"):
        im.save(tmp_path / "bad.atm", frobnicate=1)
    assert not (tmp_path / "bad.atm").exists()  # Pillow removes the file it created


def test_save_to_a_file_object_and_unsupported_modes():
    buf = io.BytesIO()
    Image.fromarray(range_scene(20, 10, seed=7)).save(buf, format="ATM")
    assert codec.decode(buf.getvalue()).shape == (10, 20)
    with pytest.raises(codec.UnsupportedError, match="convert"):
        Image.new("RGBA", (4, 4)).save(io.BytesIO(), format="ATM")


def test_open_reads_only_the_header_and_decodes_on_load(tmp_path, monkeypatch):
    path = tmp_path / "lazy.atm"
    codec.write(path, range_scene(40, 30, seed=8), points=200)

    def refuse(data, **kw):
        raise AssertionError("decoded at open")

    monkeypatch.setattr(codec.stream, "decode_all", refuse)
    im = Image.open(path)
    assert im.size == (40, 30)
    with pytest.raises(AssertionError, match="decoded at open"):
        im.load()


def test_decompression_bomb_check_runs_before_decoding(tmp_path, monkeypatch):
    path = tmp_path / "big.atm"
    codec.write(path, range_scene(40, 30, seed=9), points=100)
    monkeypatch.setattr(codec.stream, "decode_all", lambda *a, **k: pytest.fail("decoded a bomb"))
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 500)  # 1,200 pixels is over twice that
    with pytest.raises(Image.DecompressionBombError):
        Image.open(path)


def test_other_files_are_not_claimed(tmp_path):
    path = tmp_path / "x.png"
    Image.new("L", (3, 3)).save(path)
    assert Image.open(path).format == "PNG"
    assert not codec.pil._accept(b"\x89PNG\r\n\x1a\n")


def test_imageio_pillow_path_reads_atm(tmp_path):
    import imageio.v3 as iio

    image = range_scene(40, 30, seed=10, dtype=np.uint16)
    path = tmp_path / "z.atm"
    codec.write(path, image, points=400)
    got = iio.imread(path, plugin="pillow")
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, codec.read(path))


def test_import_codec_does_not_import_pillow():
    code = "import sys, codec; codec.decode; print('PIL' in sys.modules, 'cv2' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_save_ignores_the_options_generic_pipelines_pass(tmp_path):
    im = Image.fromarray(range_scene(32, 24, seed=8))
    path = tmp_path / "generic.atm"
    im.save(path, optimize=True, dpi=(72, 72), points=80)
    assert codec.info(path.read_bytes())["width"] == 32
    with pytest.raises(codec.OptionError, match="quailty"):
        im.save(tmp_path / "typo.atm", optimize=True, quailty=50)


def test_open_a_gray_file_with_a_channel_axis(tmp_path):
    """Pillow has no H x W x 1 mode: a file with an `axis` chunk (ATM.md §4.9) opens as
    the gray image it is."""
    image = range_scene(40, 30, seed=1)
    path = tmp_path / "x.atm"
    codec.write(path, image[:, :, None], points=300)
    assert codec.read(path).shape == (30, 40, 1)
    with Image.open(path) as im:
        assert im.mode == "L" and im.size == (40, 30)
        np.testing.assert_array_equal(np.asarray(im), codec.read(path)[:, :, 0])

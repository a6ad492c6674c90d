"""Bad input to `atm` that is not an image file: one line, no traceback."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from codec.errors import LimitError
from codec.files import read_image
from tests.test_cli import atm
from tests.test_cli_outputs import refused, scene  # noqa: F401 (scene is a fixture)


def test_deeply_nested_metadata_is_one_line(scene, tmp_path):
    deep = '{"a": ' + "[" * 5000 + "]" * 5000 + "}"
    refused(atm("encode", scene, tmp_path / "m.atm", "--metadata", deep), "--metadata is nested too deeply")
    assert not (tmp_path / "m.atm").exists()


@pytest.mark.parametrize("array", [np.zeros((8, 8), bool), np.zeros((8, 8), np.complex64), np.zeros(8, np.uint8)])
def test_compare_refuses_arrays_that_are_not_images_in_one_line(tmp_path, array):
    np.save(tmp_path / "x.npy", array)
    r = atm("compare", tmp_path / "x.npy", tmp_path / "x.npy")
    err = r.stderr.decode()
    assert r.returncode == 1 and err.startswith("atm: error: cannot compare an array") and err.count("\n") == 1


def png_header(width: int, height: int) -> bytes:
    """A PNG's signature and IHDR chunk (8-bit gray), and no pixel data."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))


def test_an_image_header_over_the_pixel_limit_is_refused_before_decoding(tmp_path):
    (tmp_path / "bomb.png").write_bytes(png_header(17000, 17000) + bytes(64))
    r = atm("encode", tmp_path / "bomb.png", tmp_path / "x.atm")
    assert r.returncode == 1 and b"17000x17000 = 289,000,000 pixels, over the limit" in r.stderr, r.stderr
    header = "{'descr': '|u1', 'fortran_order': False, 'shape': (20000, 20000), }".ljust(117) + "\n"
    (tmp_path / "bomb.npy").write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode())
    with pytest.raises(LimitError, match="20000x20000"):
        read_image(tmp_path / "bomb.npy")
    assert not (tmp_path / "x.atm").exists()


def test_a_picture_header_over_the_pixel_limit_is_one_line(tmp_path):
    """A GIF whose header declares 20000 x 20000 pixels: refused from its header with one
    line naming the file (Pillow's own bomb check raised a traceback), nothing written."""
    def gif(side: int) -> bytes:
        return (b"GIF89a" + struct.pack("<HHBBB", side, side, 0, 0, 0) + b"\x2c"
                + struct.pack("<HHHHB", 0, 0, side, side, 0) + b"\x08\x02\x4c\x01\x00\x3b")

    (tmp_path / "bomb.gif").write_bytes(gif(20000))
    r = atm("encode", tmp_path / "bomb.gif", tmp_path / "x.atm")
    assert r.returncode == 1 and r.stderr.count(b"\n") == 1 and b"bomb.gif" in r.stderr, r.stderr
    assert not (tmp_path / "x.atm").exists()

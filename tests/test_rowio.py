"""`atm encode` reading .npy files as rows: byte order, and headers that lie."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from tests.synthetic import range_scene
from tests.test_cli import atm


@pytest.mark.parametrize("dtype", [">u2", ">f4", ">f8"])
def test_a_big_endian_npy_encodes_like_a_native_one(tmp_path, dtype):
    z = range_scene(64, 48, seed=5, dtype=np.uint16).astype(dtype)
    np.save(tmp_path / "big.npy", z)
    np.save(tmp_path / "native.npy", z.astype(z.dtype.newbyteorder("=")))
    for name in ("big", "native"):
        r = atm("encode", tmp_path / f"{name}.npy", tmp_path / f"{name}.atm", "--points", 300)
        assert r.returncode == 0, r.stderr
    assert (tmp_path / "big.atm").read_bytes() == (tmp_path / "native.atm").read_bytes()


def test_an_npy_header_that_lies_about_its_size_is_one_line(tmp_path):
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (200000, 200000), }".ljust(117) + "\n"
    npy = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode()
    (tmp_path / "lies.npy").write_bytes(npy + bytes(64))
    (tmp_path / "cut.npy").write_bytes(npy[:-10])
    for name in ("lies", "cut"):
        r = atm("encode", tmp_path / f"{name}.npy", tmp_path / "x.atm")
        err = r.stderr.decode()
        assert r.returncode == 1 and err.startswith(f"atm: error: {tmp_path / name}.npy: not a readable .npy array")
        assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.atm").exists()

"""Batch encode takes every format a single-file encode takes (codec.files.READABLE)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import codec
from codec.cli.main import main
from codec.files import READABLE, atomic_write


def sample(ext: str) -> bytes:
    """A small image file of that format."""
    import cv2

    y, x = np.mgrid[:48, :64]  # JPEG 2000 wants 32 pixels or more a side
    gray = ((x * 7 + y * 5) % 200 + 20).astype(np.uint8)
    if ext == ".npy":
        import io

        buf = io.BytesIO()
        np.save(buf, gray)
        return buf.getvalue()
    if ext in (".tif", ".tiff"):
        from codec import geotiff

        return geotiff.write(gray)
    image = {".pfm": gray.astype(np.float32) / 7, ".gif": np.dstack([gray] * 3), ".ppm": np.dstack([gray] * 3)}.get(ext, gray)
    ok, buf = cv2.imencode(ext, image)
    if not ok:
        raise AssertionError(f"OpenCV cannot write a test {ext}")
    return buf.tobytes()


def test_batch_takes_every_format_single_file_encode_takes(tmp_path: Path):
    src = tmp_path / "in"
    src.mkdir()
    for ext in READABLE:
        atomic_write(src / f"img_{ext[1:]}{ext}", sample(ext))
    for path in sorted(src.iterdir()):
        assert main(["encode", "--quiet", str(path), str(tmp_path / "single.atm"), "--points", "40"]) == 0, path.name
    out = tmp_path / "out"
    assert main(["encode", "--quiet", "--jobs", "1", str(src), str(out), "--points", "40"]) == 0
    made = sorted(p.name for p in out.iterdir())
    assert made == sorted(f"img_{ext[1:]}.atm" for ext in READABLE)
    pfm = codec.read(out / "img_pfm.atm")
    assert pfm.dtype == np.float32  # the disparity format keeps its float samples

"""The numcodecs codec `atm`: zarr arrays with .atm chunks, and dask writing them from
a distributed cluster (the way to scale out over a raster too big for one machine)."""

from __future__ import annotations

import numpy as np
import pytest

numcodecs = pytest.importorskip("numcodecs")
zarr = pytest.importorskip("zarr")

import codec  # noqa: E402
from codec.numcodecs import ATM  # noqa: E402


def terrain(height: int, width: int, dtype=np.float32) -> np.ndarray:
    y, x = np.mgrid[:height, :width].astype(np.float64)
    z = 300 + 40 * np.sin(x / 11.0) + 25 * np.cos(y / 7.0) + 0.8 * x
    z[:, width // 3 :] += 35  # a cliff
    return z.astype(dtype) if dtype != np.int16 else np.round(z).astype(np.int16)


def test_entry_point_registers_the_codec():
    c = numcodecs.get_codec({"id": "atm", "max_error": 0.25, "nodata": -9999})
    assert isinstance(c, ATM) and c.max_error == 0.25
    assert numcodecs.get_codec(c.get_config()) == c


def test_chunked_zarr_array_round_trips_within_the_bound(tmp_path):
    z = terrain(150, 170)
    z[30:45, 60:90] = np.nan  # holes stay holes
    a = zarr.create_array(tmp_path / "dem.zarr", shape=z.shape, chunks=(64, 64), dtype=z.dtype,
                          zarr_format=2, compressors=ATM(max_error=0.5), fill_value=np.nan)
    a[:] = z
    b = zarr.open_array(tmp_path / "dem.zarr", mode="r")
    out = b[:]
    assert isinstance(b.metadata.compressor, ATM)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(z))
    assert np.nanmax(np.abs(out - z)) <= 0.5
    # each stored chunk is an .atm file
    chunk = (tmp_path / "dem.zarr" / "0.0").read_bytes()
    assert codec.info(chunk)["width"] == 64


def test_lossless_int16_chunks_with_nodata_are_exact(tmp_path):
    z = terrain(90, 100, np.int16)
    z[10:20, 10:20] = -32768
    a = zarr.create_array(tmp_path / "i.zarr", shape=z.shape, chunks=(40, 60), dtype=z.dtype,
                          zarr_format=2, compressors=ATM(lossless=True, nodata=-32768), fill_value=-32768)
    a[:] = z
    np.testing.assert_array_equal(zarr.open_array(tmp_path / "i.zarr", mode="r")[:], z)


def test_bad_settings_and_chunks_are_atm_errors():
    with pytest.raises(codec.OptionError, match="lossless"):
        ATM(lossless=True, max_error=1)
    with pytest.raises(codec.UnsupportedError, match="2-D chunks"):
        ATM(points=10).encode(np.zeros((2, 3, 4, 5), np.uint8))


def test_dask_to_zarr_on_a_two_worker_local_cluster(tmp_path):
    da = pytest.importorskip("dask.array")
    distributed = pytest.importorskip("distributed")
    z = terrain(160, 200)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=40) as cluster, \
            distributed.Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        arr = da.from_array(z, chunks=(80, 100))
        da.to_zarr(arr, str(tmp_path / "big.zarr"), zarr_format=2,
                   compressors=ATM(max_error=0.25), fill_value=np.nan)
        back = da.from_zarr(str(tmp_path / "big.zarr")).compute()
    assert np.abs(back - z).max() <= 0.25


def test_zarr_format_3_array_with_the_atm_serializer(tmp_path):
    pytest.importorskip("zarr.codecs.numcodecs")
    from codec.zarr3 import ATM as ATM3

    z = terrain(90, 110)
    z[5:15, 20:40] = np.nan
    with pytest.warns(UserWarning, match="not in the Zarr version 3 specification"):
        serializer = ATM3(max_error=0.25)
    a = zarr.create_array(tmp_path / "v3.zarr", shape=z.shape, chunks=(48, 64), dtype=z.dtype,
                          serializer=serializer, compressors=None, fill_value=np.nan)
    a[:] = z
    # a new process's view: the array's metadata names the codec, the entry point finds it
    code = (
        "import sys, zarr, numpy as np; a = zarr.open_array(sys.argv[1], mode='r'); "
        "np.save(sys.argv[2], a[:]); print(a.metadata.codecs[0].codec_name)"
    )
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-W", "ignore", "-c", code, str(tmp_path / "v3.zarr"), str(tmp_path / "back.npy")],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "numcodecs.atm"
    out = np.load(tmp_path / "back.npy")
    np.testing.assert_array_equal(np.isnan(out), np.isnan(z))
    assert np.nanmax(np.abs(out - z)) <= 0.25


def test_lossless_float_chunks_keep_their_bits():
    """ATM(lossless=True) on float32 chunks: every sample's bits, NaN holes, -0.0 and
    fractions no step captures (quality=100, what it gave before, was within half a
    16-bit step only)."""
    rng = np.random.default_rng(8)
    chunk = (terrain(30, 40, np.int16).astype(np.float64) * 0.731 + rng.normal(0, 0.01, (30, 40))).astype(np.float32)
    chunk[5:9, 10:20] = np.nan
    chunk[0, 0] = -0.0
    c = ATM(lossless=True)
    back = c.decode(c.encode(chunk))
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back.view(np.uint32), chunk.view(np.uint32))


def test_a_chunk_with_a_channel_axis_comes_back_in_its_shape():
    """An (r, c, 1) chunk decodes as (r, c, 1) without out= (ATM.md §4.9's axis chunk),
    and into a numcodecs out= buffer of either shape."""
    chunk = terrain(30, 40, np.int16)[:, :, None]
    c = ATM(lossless=True)
    data = c.encode(chunk)
    back = c.decode(data)
    assert back.shape == (30, 40, 1) and back.dtype == np.int16
    np.testing.assert_array_equal(back, chunk)
    np.testing.assert_array_equal(c.decode(data, out=np.empty((30, 40), np.int16)), chunk[:, :, 0])

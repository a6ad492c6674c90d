"""GeoTIFF in and out: georeferencing kept through `atm encode` / `atm decode … .tif`,
checked with rasterio (what a GIS user reads GeoTIFFs with); nodata becomes holes; the
compressions GDAL writes read without warnings."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import codec
from codec import geotiff
from codec.cli.main import main
from tests.corpus import range_data

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import Affine  # noqa: E402


def shared_file(name: str) -> Path:
    """A file of the project's shared range data (tests.corpus.range_data)."""
    path = range_data() / name
    if path.exists():
        return path
    if os.environ.get("CI"):
        pytest.fail(f"CI must have shared/range-data/{name} beside the repository")
    pytest.skip(f"shared/range-data/{name} is not here")


def dem(height: int, width: int, seed: int) -> np.ndarray:
    """A smooth terrain in metres with a cliff."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:height, :width].astype(np.float64)
    z = 800 + 120 * np.sin(x / 9.0) * np.cos(y / 13.0) + 2.5 * x + rng.normal(0, 0.3, (height, width))
    z[:, width // 2 :] += 60  # a cliff: a wall
    return z


def write_geotiff(path: Path, image: np.ndarray, nodata, compress: str, predictor: int = 1) -> None:
    with rasterio.open(
        path, "w", driver="GTiff", width=image.shape[1], height=image.shape[0], count=1,
        dtype=image.dtype, crs="EPSG:32633", transform=Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4650000.0),
        nodata=nodata, compress=compress, predictor=predictor,
    ) as dst:
        dst.write(image, 1)


def round_trip(tmp_path: Path, src: Path, *options: str) -> Path:
    atm, out = tmp_path / "x.atm", tmp_path / "out.tif"
    assert main(["encode", str(src), str(atm), *options]) == 0
    assert main(["decode", str(atm), str(out)]) == 0
    return out


def assert_georeferenced_alike(a: Path, b: Path) -> None:
    with rasterio.open(a) as x, rasterio.open(b) as y:
        assert y.crs == x.crs and y.crs is not None
        assert y.transform == x.transform
        assert y.nodata == x.nodata or (np.isnan(y.nodata) and np.isnan(x.nodata))
        assert y.dtypes == x.dtypes


@pytest.mark.parametrize(
    "dtype, nodata, compress, predictor",
    [(np.int16, -32768, "zstd", 2), (np.float32, -9999.0, "lzw", 3), (np.float32, -9999.0, "deflate", 2)],
)
def test_geotiff_with_nodata_round_trips_georeferenced(tmp_path, capfd, dtype, nodata, compress, predictor):
    z = dem(70, 90, seed=1)
    image = (np.round(z) if dtype == np.int16 else z).astype(dtype)
    image[20:30, 10:25] = nodata
    src = tmp_path / "dem.tif"
    write_geotiff(src, image, nodata, compress, predictor)
    capfd.readouterr()
    out = round_trip(tmp_path, src, "--max-error", "1.5")
    assert capfd.readouterr().err == ""  # no TIFF warnings (no OpenCV in the way)
    assert_georeferenced_alike(src, out)
    with rasterio.open(out) as r:
        decoded = r.read(1)
    holes = image == nodata
    np.testing.assert_array_equal(decoded == nodata, holes)  # GDAL nodata became the holes
    err = np.abs(decoded[~holes].astype(np.float64) - image[~holes])
    assert err.max() <= 1.5


def test_srtm_dem_round_trips_georeferenced(tmp_path):
    src = shared_file("srtm_dem.tif")
    out = round_trip(tmp_path, src, "--max-error", "3")
    assert_georeferenced_alike(src, out)
    with rasterio.open(src) as a, rasterio.open(out) as b:
        x, y = a.read(1).astype(np.int64), b.read(1).astype(np.int64)
    assert np.abs(x - y).max() <= 3


def test_info_shows_georeferencing(tmp_path, capsys):
    src = tmp_path / "dem.tif"
    write_geotiff(src, np.round(dem(30, 40, seed=2)).astype(np.int16), -32768, "deflate")
    atm = tmp_path / "x.atm"
    assert main(["encode", str(src), str(atm), "--points", "200"]) == 0
    capsys.readouterr()
    assert main(["info", str(atm)]) == 0
    text = capsys.readouterr().out
    assert "int16" in text and "CRS EPSG:32633" in text and "origin (500000, 4650000), pixel size 30 x -30" in text
    assert "holes decode to -32768" in text and "units horizontal metre" in text
    assert main(["info", "--json", str(atm)]) == 0
    record = json.loads(capsys.readouterr().out)["metadata"]["geotiff"]
    assert record["GDAL_NODATA"] == "-32768" and record["ModelPixelScale"][:2] == [30.0, 30.0]


def test_record_tags_are_written_back_as_read(tmp_path):
    """The tags themselves, read with tifffile, not only what rasterio makes of them."""
    tifffile = pytest.importorskip("tifffile")
    src = tmp_path / "dem.tif"
    write_geotiff(src, dem(20, 30, seed=3).astype(np.float32), -9999.0, "deflate")
    out = round_trip(tmp_path, src, "--points", "100")
    with tifffile.TiffFile(src) as a, tifffile.TiffFile(out) as b:
        for name, (code, _) in geotiff.TAGS.items():
            ta, tb = a.pages.first.tags.get(code), b.pages.first.tags.get(code)
            assert (ta is None) == (tb is None), name
            if ta is not None:
                assert ta.dtype == tb.dtype and np.array_equal(np.atleast_1d(ta.value), np.atleast_1d(tb.value)), name


def test_pixel_is_point_and_model_transformation_summaries():
    keys = [1, 1, 0, 2, 1025, 0, 1, 2, 3072, 0, 1, 32633]
    point = geotiff.summarise({"GeoKeyDirectory": keys, "ModelPixelScale": [2.0, 3.0, 0.0], "ModelTiepoint": [0, 0, 0, 100.0, 200.0, 0]})
    assert point["crs"] == "EPSG:32633" and point["transform"] == [2.0, 0.0, 99.0, 0.0, -3.0, 201.5]
    matrix = [2.0, 0.5, 0, 100.0, 0.25, -3.0, 0, 200.0, 0, 0, 0, 0, 0, 0, 0, 1]
    area = geotiff.summarise({"GeoKeyDirectory": [1, 1, 0, 0], "ModelTransformation": matrix})
    assert area["transform"] == [2.0, 0.5, 100.0, 0.25, -3.0, 200.0] and "crs" not in area


def test_nodata_that_is_no_sample_is_ignored():
    assert geotiff.nodata_value("-9999", np.dtype(np.uint16)) is None
    assert geotiff.nodata_value("65535", np.dtype(np.uint16)) == 65535
    assert np.isnan(geotiff.nodata_value("nan", np.dtype(np.float32)))
    assert geotiff.nodata_value("none", np.dtype(np.float32)) is None


def test_damaged_tiff_is_an_atm_error(tmp_path):
    src = tmp_path / "dem.tif"
    write_geotiff(src, np.zeros((8, 8), np.int16), None, "zstd")
    data = src.read_bytes()
    with pytest.raises(codec.ATMError, match="not a readable TIFF"):
        geotiff.read(data[:40], "cut.tif")


def test_int16_decodes_to_tif_or_npy_only(tmp_path):
    atm = tmp_path / "dem.atm"
    codec.write(atm, np.full((8, 8), -5, np.int16), points=10)
    assert main(["decode", str(atm), str(tmp_path / "dem.png")]) == 1
    assert not (tmp_path / "dem.png").exists()
    assert main(["decode", str(atm), str(tmp_path / "dem.npy")]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "dem.npy"), np.full((8, 8), -5, np.int16))


@pytest.mark.parametrize("dtype, nodata", [(np.int16, -32768), (np.float32, -9999.5), (np.float32, None)])
def test_decoded_tif_names_its_holes_for_gis_software(tmp_path, dtype, nodata):
    """A file's holes (a user's --nodata, or NaN) come back as the TIFF's GDAL nodata,
    overriding a source tag that says otherwise."""
    image = np.round(dem(20, 30, seed=4)).astype(dtype)
    image[2:5, 3:9] = np.nan if nodata is None else nodata
    src = tmp_path / "dem.tif"
    write_geotiff(src, image, -1.0 if dtype == np.int16 else None, "deflate")  # a tag that is not the holes
    options = [] if nodata is None else ["--nodata", str(nodata)]
    out = round_trip(tmp_path, src, "--max-error", "1", *options)
    with rasterio.open(out) as r:
        decoded, tag = r.read(1), r.nodata
        assert r.crs == "EPSG:32633"
    holes = np.isnan(image) if nodata is None else image == nodata
    if nodata is None:
        assert np.isnan(tag)
        np.testing.assert_array_equal(np.isnan(decoded), holes)
    else:
        assert tag == nodata
        np.testing.assert_array_equal(decoded == nodata, holes)


def test_tiled_zstd_geotiff_reads_as_rasterio_reads_it(tmp_path):
    """GDAL's cloud-optimised layout: tiles, ZSTD, horizontal predictor."""
    z = np.round(dem(50, 70, seed=5)).astype(np.int16)
    src = tmp_path / "tiled.tif"
    with rasterio.open(
        src, "w", driver="GTiff", width=70, height=50, count=1, dtype="int16", crs="EPSG:4326",
        transform=Affine(0.001, 0.0, 7.0, 0.0, -0.001, 46.0), nodata=-32768,
        tiled=True, blockxsize=16, blockysize=16, compress="zstd", predictor=2,
    ) as dst:
        dst.write(z, 1)
    raster = geotiff.read(src.read_bytes(), src.name)
    np.testing.assert_array_equal(raster.image, z)
    assert raster.nodata == -32768 and raster.record["crs"] == "EPSG:4326"
    assert raster.record["transform"] == [0.001, 0.0, 7.0, 0.0, -0.001, 46.0]

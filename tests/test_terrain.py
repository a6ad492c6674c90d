"""The mesh as terrain: OBJ/PLY heights in data units, an overlay that stretches the
pixels with data, and Cesium quantized-mesh tiles read back by an independent reader
(the quantized-mesh-tile package)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import codec
from codec import export, terrain
from codec.cli.main import main
from tests.test_geotiff import shared_file

qmt = pytest.importorskip("quantized_mesh_tile.terrain")


def read_tile(data: bytes, bounds) -> "qmt.TerrainTile":
    import io

    west, south, east, north = bounds
    tile = qmt.TerrainTile(west=west, south=south, east=east, north=north)
    tile.fromBytesIO(io.BytesIO(data))
    return tile


def geographic(height: int, width: int) -> dict:
    step = 1 / 1200
    return {"geotiff": {"crs": "EPSG:4326", "transform": [step, 0.0, 7.0, 0.0, -step, 46.5]}}


def test_srtm_tile_reads_back_with_its_vertices_and_heights(tmp_path):
    src = shared_file("srtm_dem.tif")
    atm, tile_path = tmp_path / "dem.atm", tmp_path / "dem.terrain"
    bound = 12
    # terrain is the mesh itself: --no-residual keeps it within the bound
    assert main(["encode", str(src), str(atm), "--max-error", str(bound), "--no-residual"]) == 0
    assert main(["mesh", str(atm), str(tile_path)]) == 0
    data = atm.read_bytes()
    info = codec.info(data)
    dem = codec.decode(data)  # holes: none here (the nodata tag is never used)
    original = codec.files.read_image(src).astype(np.float64)
    bounds = terrain.geographic_bounds(terrain.load(data))
    tile = read_tile(tile_path.read_bytes(), bounds)
    assert len(tile.u) == info["vertices"] and len(tile.indices) == 3 * info["triangles"]
    lon, lat, h = np.array(tile.getVerticesCoordinates()).T
    west, south, east, north = bounds
    x = np.rint((lon - west) / (east - west) * (dem.shape[1] - 1)).astype(int)
    y = np.rint((north - lat) / (north - south) * (dem.shape[0] - 1)).astype(int)
    step = (tile.header["maximumHeight"] - tile.header["minimumHeight"]) / terrain.MAX
    assert np.abs(h - original[y, x]).max() <= bound + step / 2 + 1e-6
    assert len(set(zip(x.tolist(), y.tolist()))) == len(x)  # the same vertices, none merged
    # the same triangles (high-water-mark indices decoded by the reader)
    mesh = codec.decode_mesh(data)
    key = mesh.vertices[:, 1] * dem.shape[1] + mesh.vertices[:, 0]
    ours = {tuple(sorted(t)) for t in key[mesh.triangles].tolist()}
    read = np.array(tile.indices).reshape(-1, 3)
    theirs = {tuple(sorted(t)) for t in (y * dem.shape[1] + x)[read].tolist()}
    assert theirs == ours
    # the edge lists name exactly the vertices on the tile's borders
    assert sorted(tile.westI) == sorted(np.flatnonzero(x == 0).tolist())
    assert sorted(tile.northI) == sorted(np.flatnonzero(y == 0).tolist())


def test_tile_with_more_than_65536_vertices_aligns_its_32_bit_indices():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 4000, (301, 301)).astype(np.uint16)  # every pixel a vertex
    data = codec.encode(image, points=301 * 301, mesher="uniform", metadata=geographic(301, 301))
    dem = terrain.load(data)
    tile = terrain.to_quantized_mesh(dem)
    n = struct.unpack_from("<I", tile, 88)[0]
    assert n == 301 * 301 and (92 + 6 * n) % 4 == 2
    assert tile[92 + 6 * n : 94 + 6 * n] == b"\0\0"
    # quantized-mesh-tile skips no padding: give it the tile without the two bytes
    back = read_tile(tile[: 92 + 6 * n] + tile[94 + 6 * n :], terrain.geographic_bounds(dem))
    assert len(back.indices) == 3 * len(dem.mesh.triangles)
    h = np.array(back.getVerticesCoordinates())[:, 2]
    assert np.abs(np.sort(h) - np.sort(image.reshape(-1).astype(float))).max() <= 4000 / terrain.MAX


def test_tile_needs_geographic_coordinates():
    data = codec.encode(np.zeros((20, 20), np.uint16), points=20)
    with pytest.raises(codec.UnsupportedError, match="EPSG:4326.*gdalwarp"):
        terrain.to_quantized_mesh(terrain.load(data))


@pytest.mark.parametrize("fmt", ["obj", "ply"])
def test_mesh_heights_are_in_data_units(tmp_path, fmt):
    y, x = np.mgrid[:40, :50]
    z = (1234.5 + 3.25 * x - 1.5 * y + 0.01 * x * y).astype(np.float32)
    atm, out = tmp_path / "dem.atm", tmp_path / f"dem.{fmt}"
    codec.write(atm, z, max_error=0.05, residual=False)  # the mesh itself within the bound
    assert main(["mesh", str(atm), str(out)]) == 0
    if fmt == "obj":
        rows = [line.split()[1:4] for line in out.read_text().splitlines() if line.startswith("v ")]
        v = np.array(rows, dtype=np.float64)
    else:
        raw = out.read_bytes()
        count = int(raw.split(b"element vertex ")[1].split(b"\n")[0])
        body = raw[raw.index(b"end_header\n") + len(b"end_header\n") :]
        v = np.frombuffer(body, "<f4", 3 * count).reshape(count, 3).astype(np.float64)
    xs, ys = v[:, 0].astype(int), v[:, 1].astype(int)
    tolerance = 0.05 + (1e-4 if fmt == "obj" else 1e-3)  # PLY's float32
    assert np.abs(v[:, 2] - z[ys, xs]).max() <= tolerance


def test_overlay_stretches_the_pixels_with_data_only():
    y, x = np.mgrid[:30, :40]
    dem = (1500 + 10 * x + y).astype(np.float32)
    dem[:5, :5] = -9999
    rgb = export.display_rgb(dem, nodata=-9999)
    valid = dem != -9999
    assert rgb[valid].min() == 0 and rgb[valid].max() == 255
    assert (rgb[~valid] == 0).all()
    washed = export.display_rgb(dem)  # nodata in the stretch: the terrain is one grey
    assert washed[valid].min() > 200


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16, np.uint16])
def test_build_mesh_takes_encode_bounds_and_sample_types(dtype):
    y, x = np.mgrid[:60, :70]
    z = 900 + 30 * np.sin(x / 6.0) + 0.7 * y
    z[:, 40:] += 25
    image = z.astype(dtype) if np.dtype(dtype).kind == "f" else np.round(z).astype(dtype)
    bound = 0.3 if np.dtype(dtype).kind == "f" else 1
    mesh = codec.build_mesh(image, max_error=bound)
    data = codec.encode(image, max_error=bound, band_height=59, residual=False)
    assert len(mesh.vertices) == codec.info(data)["vertices"]
    assert mesh.dtype == (np.float32 if np.dtype(dtype).kind == "f" else dtype)
    at = image[mesh.vertices[:, 1], mesh.vertices[:, 0]].astype(np.float64)
    assert np.abs(mesh.values.astype(np.float64) - at).max() <= bound + 1e-4  # data units
    assert len(codec.build_mesh(image, quality=90).vertices) >= 3


def test_mesh_of_a_layered_file_says_it_is_a_preview(tmp_path, capsys):
    # max_error's default is the residual layer, beside which the mesh is a preview:
    # `atm mesh` says so (and how to get a mesh within the bound); with --no-residual, silence
    y, x = np.mgrid[:40, :50]
    z = (1234.5 + 3.25 * x - 1.5 * y + 0.3 * np.sin(x)).astype(np.float32)
    src = tmp_path / "dem.npy"
    np.save(src, z)
    for extra, noted in (([], True), (["--no-residual"], False)):
        atm, out = tmp_path / "dem.atm", tmp_path / "dem.obj"
        assert main(["encode", str(src), str(atm), "--max-error", "0.05", "--force", *extra]) == 0
        capsys.readouterr()
        assert main(["mesh", str(atm), str(out), "--force"]) == 0
        err = capsys.readouterr().err
        assert ("light preview" in err and "--no-residual" in err) == noted, err

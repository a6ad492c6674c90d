"""The same terrain mesh as an .atm file, as Draco and as a gzipped quantized-mesh tile,
and the vertices pydelatin needs at the same maximum error (issue #22).

    python benchmarks/mesh_formats.py                 # the SRTM DEM and a synthetic one
    python benchmarks/mesh_formats.py --quick         # a 96 x 80 synthetic DEM only

For each DEM and maximum error E (metres), .atm encodes the DEM with max_error=E; its
mesh (vertices, triangles, heights in metres) is then compressed by the peers: Draco
(DracoPy, compression level 10, 16-bit quantisation: positions to better than a pixel
and heights to range / 65,536) and quantized-mesh-1.0 (quantized-mesh-encoder, heights to
range / 32,767, then gzip -9, as terrain servers send it). The peers store the same
vertices and triangles: sizes compare only how each format codes one mesh.
pydelatin (greedy insertion to max_error=E, heights as float) gives a vertex count to
compare the mesher with. Sizes and counts are deterministic: one run each.

Needs the bench extra (DracoPy, quantized-mesh-encoder, pydelatin, tifffile).
"""

from __future__ import annotations

import argparse
import gzip
import io
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import codec  # noqa: E402
from codec import terrain  # noqa: E402
from tests.corpus import range_data  # noqa: E402


def synthetic_dem(height: int, width: int) -> np.ndarray:
    """Rolling hills with a cliff, in metres (uint16), deterministic."""
    rng = np.random.default_rng(22)
    y, x = np.mgrid[:height, :width].astype(np.float64)
    z = 1500 + 80 * np.sin(x / 17.0) * np.cos(y / 23.0) + 0.9 * x + rng.normal(0, 1.0, (height, width))
    z[:, width // 2 :] += 120
    return np.round(z).astype(np.uint16)


def dems(quick: bool) -> dict[str, tuple[np.ndarray, dict | None]]:
    """Name -> (elevations, geotiff metadata or None)."""
    out = {"synthetic": (synthetic_dem(80, 96) if quick else synthetic_dem(400, 480), None)}
    if not quick:
        path = range_data() / "srtm_dem.tif"
        if path.exists():
            from codec import geotiff

            raster = geotiff.read(path.read_bytes(), path.name)
            out["srtm_dem"] = (raster.image, raster.metadata)
    return out


def draco_bytes(mesh, heights: np.ndarray) -> int:
    import DracoPy

    points = np.column_stack([mesh.vertices.astype(np.float64), heights]).astype(np.float32)
    return len(DracoPy.encode(points, mesh.triangles.astype(np.uint32), quantization_bits=16, compression_level=10))


def quantized_mesh_gz_bytes(mesh, heights: np.ndarray) -> int:
    import quantized_mesh_encoder

    w, h = mesh.width, mesh.height
    # positions in degrees over a small tile; the format quantises them to the tile anyway
    bounds = (7.0, 46.0, 7.0 + 0.001 * (w - 1), 46.0 + 0.001 * (h - 1))
    lon = bounds[0] + 0.001 * mesh.vertices[:, 0]
    lat = bounds[3] - 0.001 * mesh.vertices[:, 1]
    positions = np.column_stack([lon, lat, heights]).astype(np.float32)
    buf = io.BytesIO()
    quantized_mesh_encoder.encode(buf, positions, mesh.triangles.reshape(-1).astype(np.uint32), bounds=bounds)
    return len(gzip.compress(buf.getvalue(), 9, mtime=0))


def delatin_vertices(dem: np.ndarray, max_error: float) -> int:
    from pydelatin import Delatin

    return len(Delatin(dem.astype(np.float32), max_error=max_error).vertices)


def measure(name: str, dem: np.ndarray, metadata: dict | None, max_error: float) -> dict:
    data = codec.encode(dem, max_error=max_error, metadata=metadata, residual=False)  # the mesh is what is compared
    t = terrain.load(data)
    decoded = codec.decode(data).astype(np.float64)
    assert np.abs(decoded - dem).max() <= max_error  # the bound the mesh was made to
    return {
        "dem": name,
        "size": f"{dem.shape[1]}x{dem.shape[0]}",
        "E": max_error,
        "vertices": len(t.mesh.vertices),
        "delatin vertices": delatin_vertices(dem, max_error),
        "atm bytes": len(data),
        "draco bytes": draco_bytes(t.mesh, t.heights),
        "qm.gz bytes": quantized_mesh_gz_bytes(t.mesh, t.heights),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a small synthetic DEM only")
    parser.add_argument("--errors", type=float, nargs="+", default=[2.0, 5.0, 10.0], help="maximum errors, metres")
    args = parser.parse_args(argv)
    rows = [measure(name, dem, meta, e) for name, (dem, meta) in dems(args.quick).items() for e in args.errors]
    head = ["dem", "size", "E m", "vertices", "vs pydelatin", "atm bytes", "draco / atm", "qm.gz / atm"]
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for r in rows:
        print(
            f"| {r['dem']} | {r['size']} | {r['E']:g} | {r['vertices']:,} | "
            f"{r['vertices'] / r['delatin vertices']:.2f} | {r['atm bytes']:,} | "
            f"{r['draco bytes'] / r['atm bytes']:.2f} | {r['qm.gz bytes'] / r['atm bytes']:.2f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

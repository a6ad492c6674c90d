"""An .atm file's mesh as terrain: heights in data units, and Cesium quantized-mesh tiles.

quantized-mesh-1.0 (the format Cesium streams terrain in): an 88-byte header (centre,
height range, bounding sphere, horizon occlusion point, in WGS 84 earth-centred
coordinates), the vertices' u, v (0..32767 across the tile, west to east and south to
north) and heights (0..32767 across the height range), each zig-zag delta coded, the
triangles' indices high-water-mark coded, and the vertices on the tile's four edges.
The walls are edges of the triangle list (the triangulation is constrained to them), so
a viewer draws the cliffs as the encoder kept them.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass

import numpy as np

from . import container, geotiff, integers
from .errors import ATMError, UnsupportedError
from .mesh import Mesh

#: quantized-mesh's coordinate range: u, v and heights are 0..MAX.
MAX = 32767
#: WGS 84 ellipsoid: semi-major axis and flattening.
WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563
WGS84_B = WGS84_A * (1 - WGS84_F)


@dataclass(frozen=True)
class Terrain:
    """A file's merged mesh, its vertices' values in data units (metres for float or
    quantised DEMs) and its header (nodata, georeferencing)."""

    mesh: Mesh
    heights: np.ndarray
    header: container.Header

    @property
    def metadata(self) -> dict:
        return self.header.metadata or {}


def data_values(values: np.ndarray, header: container.Header) -> np.ndarray:
    """Stored samples as the values they decode to (float64): scale and offset applied
    for float data, the offset for signed integers, as they are otherwise."""
    q = values.astype(np.float64)
    if header.quant is None:
        return q
    if integers.is_signed(header.dtype):
        return q + header.quant.offset
    return header.quant.offset + header.quant.scale * q


def load(data: bytes) -> Terrain:
    """Parse .atm bytes into its mesh and heights in data units (RGB: luma). A file with
    a residual layer (codec.info's `residual`) stores a light preview mesh, not one
    within its bound: encode with residual=False for a mesh that is."""
    from .export import LUMA
    from .stream import merge_bands

    reader = container.Reader(io.BytesIO(data))
    mesh = merge_bands(list(reader))
    values = mesh.values if mesh.values.ndim == 1 else mesh.values.astype(np.float64) @ LUMA
    return Terrain(mesh, data_values(values, reader.header), reader.header)


def _geodetic_to_ecef(lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    lon, lat = np.radians(lon), np.radians(lat)
    e2 = WGS84_F * (2 - WGS84_F)
    n = WGS84_A / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.stack(
        [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1 - e2) + h) * np.sin(lat)],
        axis=1,
    )


def _horizon_occlusion_point(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The point, in ellipsoid-scaled coordinates, that is below the horizon exactly when
    every vertex is (Cesium's EllipsoidalOccluder, from the direction of the centre)."""
    radii = np.array([WGS84_A, WGS84_A, WGS84_B])
    scaled = points / radii
    direction = centre / radii
    direction /= np.linalg.norm(direction)
    magnitude = np.maximum(np.linalg.norm(scaled, axis=1), 1.0)
    unit = scaled / np.linalg.norm(scaled, axis=1)[:, None]
    cos_alpha = unit @ direction
    sin_alpha = np.linalg.norm(np.cross(unit, direction), axis=1)
    cos_beta = 1.0 / magnitude
    sin_beta = np.sqrt(magnitude**2 - 1.0) * cos_beta
    denominator = cos_alpha * cos_beta - sin_alpha * sin_beta
    if not (denominator > 0).all():
        return direction  # a tile too large to be hidden by the horizon: never culled
    return direction * float((1.0 / denominator).max())


def _zigzag_deltas(values: np.ndarray) -> bytes:
    deltas = np.diff(values.astype(np.int32), prepend=0)
    return ((deltas << 1) ^ (deltas >> 31)).astype("<u2").tobytes()


def _high_water_mark(triangles: np.ndarray) -> np.ndarray:
    """The triangle list with its vertices renumbered in order of first use, high-water
    mark coded (each index as the highest so far + 1 minus itself), and the order."""
    flat = triangles.reshape(-1)
    _, first = np.unique(flat, return_index=True)
    order = flat[np.sort(first)]  # old index of each new index
    renumber = np.empty(order.max() + 1 if len(order) else 0, np.int64)
    renumber[order] = np.arange(len(order))
    new = renumber[flat]
    highest = np.maximum.accumulate(np.concatenate([[0], new[:-1] + 1]))
    return highest - new, order


def geographic_bounds(terrain: Terrain) -> tuple[float, float, float, float]:
    """(west, south, east, north) in degrees of the first and last pixel centres, from
    the file's geotiff record; UnsupportedError naming the fix when it has none usable."""
    record = terrain.metadata.get(geotiff.KEY) or {}
    transform, crs = record.get("transform"), record.get("crs")
    if crs != "EPSG:4326" or not (isinstance(transform, list) and len(transform) == 6):
        raise UnsupportedError(
            "a quantized-mesh tile needs a DEM in longitude/latitude (EPSG:4326) with a geotransform; "
            f"this file has {'CRS ' + crs if crs else 'no CRS'}: reproject the GeoTIFF first "
            "(e.g. gdalwarp -t_srs EPSG:4326 in.tif out.tif) and encode that"
        )
    a, b, c, d, e, f = transform
    if b or d:
        raise UnsupportedError("a quantized-mesh tile needs a north-up DEM (this geotransform is rotated)")
    w, h = terrain.mesh.width, terrain.mesh.height
    lon0, lon1 = c + 0.5 * a, c + (w - 0.5) * a
    lat0, lat1 = f + 0.5 * e, f + (h - 0.5) * e
    return min(lon0, lon1), min(lat0, lat1), max(lon0, lon1), max(lat0, lat1)


def to_quantized_mesh(terrain: Terrain) -> bytes:
    """A quantized-mesh-1.0 tile (uncompressed; servers gzip it) of the whole mesh.
    Triangles touching a hole are left out, and with them vertices no triangle uses."""
    mesh = terrain.mesh
    if mesh.width < 2 or mesh.height < 2:
        raise UnsupportedError("a quantized-mesh tile needs an image at least 2 x 2 pixels")
    if max(mesh.width, mesh.height) > MAX + 1:
        raise UnsupportedError(f"a quantized-mesh tile holds at most {MAX + 1} pixels a side; cut the DEM into tiles")
    west, south, east, north = geographic_bounds(terrain)
    triangles = mesh.triangles
    if mesh.holes is not None:
        on_hole = mesh.holes[mesh.vertices[:, 1], mesh.vertices[:, 0]]
        triangles = triangles[~on_hole[triangles].any(axis=1)]
    if len(triangles) == 0:
        raise ATMError("the mesh has no triangle outside the holes: nothing to make a tile of")
    indices, order = _high_water_mark(triangles)
    x, y = mesh.vertices[order, 0].astype(np.float64), mesh.vertices[order, 1].astype(np.float64)
    heights = terrain.heights[order]
    u = np.rint(x * MAX / (mesh.width - 1)).astype(np.int64)
    v = np.rint((mesh.height - 1 - y) * MAX / (mesh.height - 1)).astype(np.int64)
    lo, hi = float(heights.min()), float(heights.max())
    hq = np.rint((heights - lo) * MAX / (hi - lo)).astype(np.int64) if hi > lo else np.zeros(len(order), np.int64)

    lon = west + (east - west) * u / MAX
    lat = south + (north - south) * v / MAX
    ecef = _geodetic_to_ecef(lon, lat, heights)
    centre = (ecef.min(axis=0) + ecef.max(axis=0)) / 2
    radius = float(np.linalg.norm(ecef - centre, axis=1).max())
    horizon = _horizon_occlusion_point(ecef, centre)

    n = len(order)
    wide = n > 65536
    out = io.BytesIO()
    out.write(struct.pack("<3d2f4d3d", *centre, lo, hi, *centre, radius, *horizon))
    out.write(struct.pack("<I", n))
    for values in (u, v, hq):
        out.write(_zigzag_deltas(values))
    if wide and out.tell() % 4:
        out.write(b"\0" * (4 - out.tell() % 4))  # IndexData32 is 4-byte aligned
    index_type = "<u4" if wide else "<u2"
    out.write(struct.pack("<I", len(triangles)))
    out.write(indices.astype(index_type).tobytes())
    for on_edge, along in ((u == 0, v), (v == 0, u), (u == MAX, v), (v == MAX, u)):
        edge = np.flatnonzero(on_edge)
        edge = edge[np.argsort(along[edge], kind="stable")]
        out.write(struct.pack("<I", len(edge)))
        out.write(edge.astype(index_type).tobytes())
    return out.getvalue()


#: build_mesh options that only an encode (refinement to a bound) honours.
BOUND_OPTIONS = ("max_error", "max_rms", "quality")


def needs_encoder(image: np.ndarray, options: dict) -> bool:
    """Whether build_mesh must go through the encoder: a size bound, or samples (float,
    signed) that the file stores with a scale and offset."""
    return any(options.get(k) is not None for k in BOUND_OPTIONS) or np.asarray(image).dtype not in (
        np.dtype(np.uint8), np.dtype(np.uint16)
    )


def build_mesh(image, **options) -> Mesh:
    """The mesh `codec.encode(image, residual=False, **options)` stores, as one piece
    (one band), its values in data units and the image's dtype (float32 for float data).
    Accepts every encode option: points, max_error, max_rms, quality, nodata, precision,
    ... A bound is met by the mesh itself (the mesh alone, not a residual layer beside a
    preview), since the mesh is what is returned."""
    from . import encoder
    from .image import as_image
    from .settings import Settings
    from .stream import merge_bands

    img = as_image(image, allow_nan=True)
    height = img.shape[0]
    options.setdefault("band_height", max(height - 1, 1))
    options = {k: v for k, v in options.items() if v is not None}
    if options.get("max_error") is not None or options.get("max_rms") is not None:
        options.setdefault("residual", False)  # the mesh is the product: it meets the bound
    mask = options.pop("mask", None)
    settings = Settings.from_options(also=("mask",), **options)
    reader = container.Reader(io.BytesIO(encoder.encode(img, settings, mask)))
    mesh = merge_bands(list(reader))
    values = data_values(mesh.values, reader.header)
    dtype = reader.header.dtype
    mesh.values = values.astype(dtype) if np.dtype(dtype).kind == "f" else np.rint(values).astype(dtype)
    return mesh

"""TIFF and GeoTIFF in and out, through tifffile (imagecodecs for LZW, ZSTD, predictors).

A GeoTIFF's georeferencing (its GeoTIFF and GDAL tags) is kept in the `geotiff` record
of the .atm metadata (format_spec/ATM.md section 4.7.1): the tags' values as they were,
so that they are written back unchanged, plus a readable summary (CRS, transform,
units). The GDAL nodata value names the holes.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from types import MappingProxyType
import warnings
from dataclasses import dataclass

import numpy as np

from .errors import ATMError, UnsupportedError

#: The reserved metadata key (ATM.md section 4.7.1).
KEY = "geotiff"

#: Record member -> (TIFF tag, TIFF type code): 12 = DOUBLE, 3 = SHORT, 2 = ASCII.
TAGS: Mapping[str, tuple[int, int]] = MappingProxyType({
    "ModelPixelScale": (33550, 12),
    "ModelTiepoint": (33922, 12),
    "ModelTransformation": (34264, 12),
    "GeoKeyDirectory": (34735, 3),
    "GeoDoubleParams": (34736, 12),
    "GeoAsciiParams": (34737, 2),
    "GDAL_METADATA": (42112, 2),
    "GDAL_NODATA": (42113, 2),
})
#: Members derived from the tags for display; never written back.
SUMMARY = ("crs", "transform", "units")

#: TIFF magic numbers: classic and BigTIFF, either byte order.
MAGICS = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")

#: GeoKey ids used by the summary (GeoTIFF 1.1, section 7).
_MODEL_TYPE, _RASTER_TYPE, _GEOGRAPHIC, _PROJECTED, _LINEAR_UNITS, _ANGULAR_UNITS, _VERTICAL_UNITS = (
    1024, 1025, 2048, 3072, 3076, 2054, 4099,
)
_UNITS = MappingProxyType({9001: "metre", 9002: "foot", 9003: "US survey foot", 9101: "radian", 9102: "degree"})


@dataclass(frozen=True)
class Raster:
    """A TIFF's first image, its GDAL nodata value (None if it has none that fits the
    sample type) and its `geotiff` record (None for a plain TIFF)."""

    image: np.ndarray
    nodata: float | None
    record: dict | None

    @property
    def metadata(self) -> dict | None:
        """The .atm metadata that keeps the georeferencing."""
        return {KEY: self.record} if self.record else None


def is_tiff(data: bytes) -> bool:
    return data[:4] in MAGICS


def _ascii(value) -> str:
    text = value.decode("latin-1") if isinstance(value, bytes) else str(value)
    return text.rstrip("\x00")


def _tag_record(tags) -> dict:
    record = {}
    for name, (code, kind) in TAGS.items():
        tag = tags.get(code)
        if tag is None:
            continue
        value = tag.value
        if kind == 2:
            record[name] = _ascii(value)
        elif kind == 3:
            record[name] = [int(v) for v in np.atleast_1d(value)]
        else:
            record[name] = [float(v) for v in np.atleast_1d(value)]
    return record


def _geokeys(directory: list[int], doubles: list[float], text: str) -> dict[int, object]:
    """GeoKey id -> value from the GeoKeyDirectory (4 shorts a key after a 4-short header)."""
    keys: dict[int, object] = {}
    for i in range(4, len(directory) - 3, 4):
        key, location, count, value = directory[i : i + 4]
        if location == 0:
            keys[key] = value
        elif location == TAGS["GeoDoubleParams"][0] and value + count <= len(doubles):
            keys[key] = doubles[value] if count == 1 else doubles[value : value + count]
        elif location == TAGS["GeoAsciiParams"][0]:
            keys[key] = text[value : value + count].rstrip("|")
    return keys


def summarise(record: dict) -> dict:
    """The display members of a record: `crs` ("EPSG:n" where the keys name one),
    `transform` (GDAL's six numbers: x = c + a col + b row, y = f + d col + e row, for
    the corner of the pixel, whatever the raster type) and `units`."""
    out: dict = {}
    keys = _geokeys(record.get("GeoKeyDirectory", []), record.get("GeoDoubleParams", []), record.get("GeoAsciiParams", ""))
    code = keys.get(_PROJECTED) or keys.get(_GEOGRAPHIC)
    if isinstance(code, int) and 0 < code < 32767:
        out["crs"] = f"EPSG:{code}"
    point = keys.get(_RASTER_TYPE) == 2  # PixelIsPoint: tie points are on pixel centres
    shift = 0.5 if point else 0.0
    if len(record.get("ModelTransformation", [])) == 16:
        m = record["ModelTransformation"]
        a, b, c, d, e, f = m[0], m[1], m[3], m[4], m[5], m[7]
        out["transform"] = [a, b, c - shift * (a + b), d, e, f - shift * (d + e)]
    elif len(record.get("ModelPixelScale", [])) >= 2 and len(record.get("ModelTiepoint", [])) >= 6:
        sx, sy = record["ModelPixelScale"][:2]
        i, j, _, x, y, _ = record["ModelTiepoint"][:6]
        c, f = x - (i + shift) * sx, y + (j + shift) * sy
        out["transform"] = [sx, 0.0, c, 0.0, -sy, f]
    unit = keys.get(_LINEAR_UNITS) if _PROJECTED in keys else keys.get(_ANGULAR_UNITS)
    units = {}
    if isinstance(unit, int):
        units["horizontal"] = _UNITS.get(unit, f"EPSG unit {unit}")
    if isinstance(keys.get(_VERTICAL_UNITS), int):
        units["vertical"] = _UNITS.get(keys[_VERTICAL_UNITS], f"EPSG unit {keys[_VERTICAL_UNITS]}")
    if units:
        out["units"] = units
    return out


def nodata_value(text: str, dtype: np.dtype) -> float | None:
    """GDAL_NODATA's value as a sample of `dtype`, or None where it is not one (GDAL
    ignores such a tag too)."""
    try:
        value = float(text.strip())
    except ValueError:
        return None
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return value if not math.isfinite(value) or abs(value) <= float(np.finfo(np.float32).max) else None
    info = np.iinfo(dtype)
    return value if value.is_integer() and info.min <= value <= info.max else None


def read(data: bytes, name: str = "input") -> Raster:
    """Decode TIFF bytes (any compression tifffile and imagecodecs read: Deflate, LZW,
    ZSTD, PackBits, ...) to the first image, gray or RGB, with its georeferencing."""
    import tifffile

    try:
        with warnings.catch_warnings():
            # tifffile warns (rather than fails) on damaged files: a failure follows anyway
            warnings.simplefilter("ignore")
            with tifffile.TiffFile(io.BytesIO(data)) as tif:
                page = tif.pages.first
                image = page.asarray()
                tags = page.tags
                record = _tag_record(tags)
                samples = page.samplesperpixel
                separate = page.planarconfig == tifffile.PLANARCONFIG.SEPARATE
    except Exception as exc:  # tifffile and imagecodecs raise many types for a damaged file
        raise ATMError(f"{name}: not a readable TIFF: {exc}") from None
    if separate and samples > 1 and image.ndim == 3:
        image = np.moveaxis(image, 0, -1)
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[:, :, :3]  # alpha: .atm has no alpha channel
    if image.ndim != 2 and not (image.ndim == 3 and image.shape[2] in (1, 3)):
        raise UnsupportedError(f"{name}: a TIFF image of shape {image.shape} is not gray or RGB")
    image = np.ascontiguousarray(image.astype(image.dtype.newbyteorder("=")))
    nodata = None
    if "GDAL_NODATA" in record:
        nodata = nodata_value(record["GDAL_NODATA"], image.dtype)
    if record:
        record.update(summarise(record))
    return Raster(image, nodata, record or None)


def nodata_text(value: float) -> str:
    """A nodata value as GDAL writes its GDAL_NODATA tag: "nan", "inf", "-inf", a whole
    number without a decimal point, or the shortest decimal that reads back the same."""
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def write(image: np.ndarray, metadata: dict | None = None, nodata: float | None = None) -> bytes:
    """TIFF bytes of `image` (Deflate-compressed), with the tags of a `geotiff` record
    in `metadata` written back as they were read; `nodata` (what the holes hold), when
    given, is the GDAL_NODATA tag, so that GIS software sees the holes."""
    import tifffile

    record = (metadata or {}).get(KEY)
    record = dict(record) if isinstance(record, dict) else {}
    if nodata is not None:
        kept = nodata_value(str(record.get("GDAL_NODATA", "")), image.dtype)
        same = kept is not None and (kept == nodata or (math.isnan(kept) and math.isnan(nodata)))
        if not same:  # the holes hold `nodata`: the tag must say so
            record["GDAL_NODATA"] = nodata_text(nodata)
    extratags = []
    if record:
        for name, (code, kind) in TAGS.items():
            value = record.get(name)
            if value is None:
                continue
            if kind == 2:
                if not isinstance(value, str):
                    raise ATMError(f"the geotiff record's {name} is not text")
                extratags.append((code, "s", 0, value, False))
            else:
                if not isinstance(value, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                    raise ATMError(f"the geotiff record's {name} is not a list of numbers")
                extratags.append((code, "H" if kind == 3 else "d", len(value), value, False))
    if image.ndim == 3 and image.shape[2] == 1:  # an (H, W, 1) decode (ATM.md §4.9): gray
        image = image[:, :, 0]
    rgb = image.ndim == 3
    out = io.BytesIO()
    tifffile.imwrite(
        out,
        image,
        photometric="rgb" if rgb else "minisblack",
        compression="zlib",
        extratags=extratags,
        metadata=None,  # no tifffile JSON description: the tags say it all
    )
    return out.getvalue()


def source_options(source, options: dict) -> dict:
    """Encoder options with a source's nodata and metadata (a GeoTIFF's) added where
    the user gave none; the user's metadata keys win over the file's."""
    options = dict(options)
    if getattr(source, "nodata", None) is not None and "nodata" not in options:
        options["nodata"] = source.nodata
    if getattr(source, "metadata", None):
        options["metadata"] = {**source.metadata, **options.get("metadata", {})}
    return options


def describe(metadata: dict) -> list[str]:
    """Readable lines about a `geotiff` record, for `atm info`."""
    record = metadata.get(KEY)
    if not isinstance(record, dict):
        return []
    lines = []
    if "crs" in record:
        lines.append(f"CRS {record['crs']}")
    if isinstance(record.get("transform"), list) and len(record["transform"]) == 6:
        a, b, c, d, e, f = record["transform"]
        lines.append(f"origin ({c:.10g}, {f:.10g}), pixel size {a:.10g} x {e:.10g}" + (f", rotation {b:g}, {d:g}" if b or d else ""))
    units = record.get("units")
    if isinstance(units, dict) and units:
        lines.append("units " + ", ".join(f"{k} {v}" for k, v in units.items()))
    if "GDAL_NODATA" in record:
        lines.append(f"GDAL nodata {record['GDAL_NODATA']}")
    return lines

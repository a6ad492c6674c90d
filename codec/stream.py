"""Streaming: encode and decode band by band, with memory bounded by the band.

Modelled on python-zstandard's stream objects: `StreamEncoder` takes rows as they come
and writes each band's chunk as soon as the band is complete; `StreamDecoder` yields
decoded rows as each band's chunk arrives.
"""

from __future__ import annotations

import numbers
from typing import BinaryIO, Callable, Iterator

import numpy as np

from . import banding, container, encoder, error_bound, holes, integers, meshcode, quantise
from .mesher import values as vertex_values
from .errors import ATMError, OptionError, UnsupportedError
from .image import SAMPLE_TYPES
from .mesh import Mesh


#: The automatic base value step, as a multiple of the first band's RMS error. Vertex
#: steps vary around it with fan area (meshcode.vertex_steps); at 1.0 the rounding
#: costs about a tenth of the squared error and buys more vertices than it costs
#: (benchmarks/rate.py: lower RMS at equal bytes than 0.7 or 1.4 on the corpus).
STEP_FACTOR = 1.0


class StreamEncoder:
    """Encode an image arriving in rows to a writable binary file object.

        with codec.StreamEncoder(f, width, height) as enc:
            for rows in source:          # any number of rows at a time
                enc.write(rows)

    The bytes equal `codec.encode(image, band_height=..., **options)` for the same image.
    The writer never seeks; at most one band (band_height + 1 rows) is held in memory.

    Size knobs: `points` (target vertex count), or a bound that refinement guarantees on
    the decoded image, per channel: `max_rms`, `max_error` (in sample units), or
    `quality` 1..100 (JPEG-like; an RMS bound, 100 = lossless).

    Float images (dtype float32/float64, one channel) are stored as 16-bit integers with
    a scale and offset: give `value_range=(lowest, highest)` and optionally `precision`
    (the quantisation step). `max_rms`/`max_error` are then in data units and include
    the quantisation error; decoding returns float32.
    """

    def __init__(
        self,
        fileobj: BinaryIO,
        width: int,
        height: int,
        *,
        dtype=np.uint8,
        channels: int = 1,
        band_height: int | None = None,
        points: int | None = None,
        mesher: str | None = None,
        quality: int | None = None,
        max_rms: float | None = None,
        max_error: float | None = None,
        value_range: tuple[float, float] | None = None,
        precision: float | None = None,
        nodata: float | None = None,
        metadata: dict | None = None,
        progress: Callable[[int, int], None] | None = None,
        value_step: int | str = "auto",
        **options,
    ):
        # progress(rows_done, height) is called after each band is written; it watches
        # the work and never changes it, so the bytes are the same with or without it
        for name, value in (("width", width), ("height", height)):
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise OptionError(f"{name} must be a positive whole number, not {value!r}")
        dtype = np.dtype(dtype)
        self._quant = None
        if integers.is_signed(dtype):
            if channels != 1:
                raise UnsupportedError("signed integer images must have one channel")
            if precision is not None:
                raise OptionError(f"{dtype} data is stored exactly; precision applies to float images only")
            value_range = value_range if value_range is not None else integers.default_range(dtype)
            if value_range is None:
                raise OptionError(
                    f"a {dtype} stream needs value_range=(lowest, highest) so that the header can "
                    "carry the offset before the data arrives"
                )
            # whole numbers with scale 1: bounds in sample units are bounds on q as they are
            self._quant = integers.plan(*value_range, dtype)
        elif dtype.kind == "f":
            if channels != 1:
                raise UnsupportedError("float images must have one channel")
            if value_range is None:
                raise OptionError(
                    "a float stream needs value_range=(lowest, highest) so that the header can "
                    "carry the quantisation before the data arrives"
                )
            self._quant = quantise.plan(*value_range, precision=precision)
            if quality is None:
                max_rms, max_error = self._quant.integer_bounds(max_rms, max_error, self._quant.scale / 2)
        elif value_range is not None or precision is not None:
            raise OptionError("value_range applies to float and signed integer images; precision to float images only")
        elif dtype not in SAMPLE_TYPES:
            raise integers.unsupported(dtype)
        storage = quantise.STORAGE if self._quant is not None else dtype
        if nodata is not None and dtype.kind in "ui":
            info = np.iinfo(dtype)
            if not (isinstance(nodata, numbers.Real) and float(nodata).is_integer() and info.min <= nodata <= info.max):
                raise OptionError(f"nodata must be a {dtype} value, not {nodata!r}")
        # float data always has a nodata value (NaN unless given), as NaN can turn up in
        # any row; integer data has one when the user names it
        self._nodata = (float("nan") if nodata is None else quantise.check_nodata(nodata)) if dtype.kind == "f" else nodata
        if channels not in (1, 3):
            raise UnsupportedError(f"{channels} channels; .atm stores 1 (gray) or 3 (RGB)")
        if band_height is None:
            band_height = banding.default_band_height(width, height)
        elif isinstance(band_height, bool) or not isinstance(band_height, numbers.Integral) or band_height < 1:
            raise OptionError(f"band_height must be a positive whole number, not {band_height!r}")
        self.width, self.height, self.dtype, self.channels = int(width), int(height), dtype, channels
        self.band_height = int(min(band_height, max(height - 1, 1)))
        self._mesher_name = mesher or encoder.DEFAULT_MESHER
        if quality is not None:
            if max_rms is not None:
                raise OptionError("give quality or max_rms, not both")
            max_rms = error_bound.quality_rms(quality, storage)
        self._bound = error_bound.Bound(max_rms=max_rms, max_error=max_error)
        if value_step != "auto" and (
            isinstance(value_step, bool) or not isinstance(value_step, numbers.Integral) or not 1 <= value_step <= 65535
        ):
            raise OptionError(f"value_step must be 'auto' or a whole number 1..65535, not {value_step!r}")
        # under an error bound, refinement decides every value exactly
        self._step = 1 if self._bound.active else (None if value_step == "auto" else int(value_step))
        self._build = encoder.mesher_build(self._mesher_name, options)
        self._values = encoder.values_method(self._build, options)
        self._options = options
        if points is None:
            points = (
                encoder.start_points(width, height)
                if self._bound.active
                else encoder.default_points(width, height)
            )
        elif isinstance(points, bool) or not isinstance(points, numbers.Integral) or points < 1:
            raise OptionError(f"points must be a positive whole number, not {points!r}")
        self._points = int(points)
        header = container.Header(
            width,
            height,
            np.dtype(np.float32) if dtype.kind == "f" else dtype,
            channels,
            quant=self._quant,
            nodata=None if self._nodata is None else float(self._nodata),
            metadata=metadata,
        )
        if metadata is not None:
            container.encode_metadata(metadata)  # checked before anything is written
        self._writer = container.Writer(fileobj, header)
        shape = (self.band_height + 1, width) + ((channels,) if channels > 1 else ())
        self._buf = np.empty(shape, storage)
        self._holes = np.zeros(shape[:2], bool)
        self._filled = 0  # rows of the current band in _buf
        self._y0 = 0  # image row of _buf[0]
        self._received = 0
        self._top: tuple[np.ndarray, np.ndarray] | None = None
        self._closed = False
        self._progress = progress
        #: Totals over the bands written so far (shared-row vertices count in both bands).
        self.bands = self.vertices = self.triangles = 0

    def write(self, rows, holes=None) -> None:
        """Add rows (an n x W, or n x W x 3, array; a single row may be 1-D).

        Pixels without data are those equal to `nodata`, NaN or infinite ones in float
        data, and those True in `holes` (an n x W boolean array, if given)."""
        if self._closed:
            raise ATMError("write() on a closed StreamEncoder")
        rows = np.asarray(rows)
        row_ndim = 1 if self.channels == 1 else 2
        if rows.ndim == row_ndim:
            rows = rows[None]
        if rows.ndim != row_ndim + 1 or rows.shape[1:] != self._buf.shape[1:]:
            raise ATMError(
                f"rows must have shape (n, {', '.join(map(str, self._buf.shape[1:]))}); got {rows.shape}"
            )
        if rows.dtype != self.dtype:
            raise ATMError(f"rows are {rows.dtype}; this stream encodes {self.dtype}")
        missing = np.zeros(rows.shape[:2], bool)
        if holes is not None:
            holes = np.asarray(holes, dtype=bool)
            if holes.shape != rows.shape[:2]:
                raise ATMError(f"holes must have shape {rows.shape[:2]}, not {holes.shape}")
            missing |= holes
        if self._nodata is not None and not np.isnan(self._nodata):
            equal = rows == self._nodata
            missing |= equal if equal.ndim == 2 else equal.all(axis=2)
        if self._quant is not None:
            missing |= ~np.isfinite(rows)
            rows = self._quant.quantise(np.where(missing, self._quant.offset, rows))
        if missing.any() and self._nodata is None:
            raise ATMError("the image has holes: give nodata= (the value hole pixels decode to)")
        if self._received + len(rows) > self.height:
            raise ATMError(f"more than the {self.height} rows declared")
        i = 0
        while i < len(rows):
            n = min(len(rows) - i, len(self._buf) - self._filled)
            self._buf[self._filled : self._filled + n] = rows[i : i + n]
            self._holes[self._filled : self._filled + n] = missing[i : i + n]
            self._filled += n
            self._received += n
            i += n
            if self._filled == len(self._buf) or self._received == self.height:
                self._flush()

    def _flush(self) -> None:
        if self._filled < 2 and self.height > 1:
            return  # only the shared row of a band already written
        band = self._buf[: self._filled]
        band_holes = self._holes[: self._filled]
        has_holes = bool(band_holes.any())
        valid_share = 1.0 - band_holes.mean() if has_holes else 1.0
        share = self._points * valid_share * (self._filled - (self._y0 > 0)) / self.height
        if has_holes:
            band = holes.fill(band, band_holes)
        mesh = self._build(band, max(4, round(share)), **self._options)
        if has_holes:
            mesh = holes.cut(mesh, band_holes.copy())
        if self._top is not None:
            mesh = banding.pin_top_row(mesh, *self._top)
        if self._received < self.height:
            # the next band starts from this band's last row: make that row good
            mesh = banding.sample_last_row(mesh, band, self._row_tolerance(mesh, band))
        if has_holes:
            fitted = vertex_values.fit(band, mesh.vertices, mesh.triangles, self._values)
            if self._top is not None:
                top = mesh.vertices[:, 1] == 0
                fitted[top] = mesh.values[top]
            mesh.values = fitted
        mesh = self._quantise(mesh, band, band_holes if has_holes else None)
        mesh = error_bound.refine(
            mesh,
            band,
            self._bound,
            values=self._values,
            pinned_rows=1 if self._top is not None else 0,
            last_band=self._received == self.height,
            valid=~band_holes if has_holes else None,
        )
        self._writer.write_band(self._y0, mesh, self._step)
        self.bands += 1
        self.vertices += len(mesh.vertices)
        self.triangles += len(mesh.triangles)
        self._top = banding.bottom_row(mesh)
        self._buf[0] = self._buf[self._filled - 1]
        self._holes[0] = self._holes[self._filled - 1]
        self._y0 += self._filled - 1
        self._filled = 1
        if self._progress is not None:
            self._progress(self._y0 + 1, self.height)

    def _row_tolerance(self, mesh: Mesh, band: np.ndarray) -> float:
        """How closely a shared row must follow the image: the error bound if there is
        one, else twice the band's RMS error (the row should not be the band's worst)."""
        if self._bound.max_error is not None:
            return float(self._bound.max_error)
        if self._bound.max_rms is not None:
            return float(self._bound.max_rms)
        from . import decoder_cpu

        diff = decoder_cpu.render(mesh).astype(np.float64) - band
        return max(1.0, 2.0 * float(np.sqrt(np.mean(diff**2))))

    def _quantise(self, mesh: Mesh, band: np.ndarray, band_holes: np.ndarray | None) -> Mesh:
        """Quantise the vertex values as the file will store them (meshcode.quantise;
        pinned first-row values stay exact), with the base step set by the first
        band at STEP_FACTOR times its RMS error, or given."""
        if self._step is None:
            mse = getattr(mesh, "decoded_mse", None) if band_holes is None else None
            if mse is None:
                from . import decoder_cpu

                diff = decoder_cpu.render(mesh).astype(np.float64) - band
                diff = diff.reshape(mesh.height, mesh.width, -1)
                if band_holes is not None:
                    diff = diff[~band_holes]
                mse = float((diff.reshape(-1, mesh.channels) ** 2).mean(axis=0).min()) if diff.size else 0.0
            self._step = max(1, int(STEP_FACTOR * np.sqrt(mse)))
        return meshcode.quantise(mesh, self._step, self._top is not None)

    def close(self) -> None:
        """Finish the file. Raises ATMError if fewer rows came than were declared."""
        if self._closed:
            return
        if self._received != self.height:
            raise ATMError(f"the stream got {self._received} of the {self.height} rows declared")
        self._writer.close()
        self._closed = True

    def __enter__(self) -> "StreamEncoder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()


class StreamDecoder:
    """Decode an .atm file from a readable binary file object, band by band.

    `width`, `height`, `dtype`, `channels` and `shape` are known once the header has
    been read (at creation). Iterating yields `(y0, rows)`: the image rows y0, y0+1, ...
    in order, each row once, as soon as each band's chunk has arrived. A damaged or
    truncated stream yields every intact band and then raises an ATMError.
    """

    def __init__(self, fileobj: BinaryIO, *, backend: str = "cpu"):
        from . import decoding

        if backend not in decoding.BACKENDS:
            raise OptionError(
                f"unknown decoder backend {backend!r}; choose one of {', '.join(decoding.BACKENDS)}"
            )
        self._reader = container.Reader(fileobj)
        self._backend = backend
        h = self._reader.header
        self.width, self.height, self.dtype, self.channels = h.width, h.height, h.dtype, h.channels
        self.shape = h.shape
        #: what hole pixels decode to (None: the file has no holes)
        self.nodata = h.nodata
        #: JSON key-values stored with the image (empty if none); meta chunks after
        #: the first band are added as they are read
        self.metadata = dict(h.metadata or {})

    def bands(self) -> Iterator[tuple[int, Mesh]]:
        """The (y0, Mesh) of each band, undecoded."""
        return iter(self._reader)

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        from . import decoding

        quant, nodata = self._reader.header.quant, self._reader.header.nodata
        for y0, mesh in self._reader:
            self.metadata.update(self._reader.header.metadata or {})
            rows = decoding.render(mesh, backend=self._backend)
            if quant is not None and integers.is_signed(self.dtype):
                rows = integers.restore(rows, quant, self.dtype)
            elif quant is not None:
                rows = quant.dequantise(rows)
            if mesh.holes is not None:
                rows[mesh.holes] = nodata
            last = y0 + mesh.height == self.height
            # the band's last row is the next band's first: emit it once, from there
            yield y0, rows if last else rows[:-1]


def decode_all(fileobj: BinaryIO, backend: str = "cpu") -> tuple[np.ndarray, dict]:
    """Decode a whole file into one array; also return its metadata."""
    dec = StreamDecoder(fileobj, backend=backend)
    out = np.empty(dec.shape, dec.dtype)
    for y0, rows in dec:
        out[y0 : y0 + len(rows)] = rows
    return out, dec.metadata


def merge_bands(bands: list[tuple[int, Mesh]]) -> Mesh:
    """One Mesh of the whole image from its bands (shared-row vertices merged)."""
    if len(bands) == 1:
        return bands[0][1]
    width = bands[0][1].width
    height = bands[-1][0] + bands[-1][1].height
    pos = np.concatenate([m.vertices + [0, y0] for y0, m in bands])
    vals = np.concatenate([m.values for _, m in bands])
    keys = pos[:, 1] * width + pos[:, 0]
    unique, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    offsets = np.cumsum([0] + [len(m.vertices) for _, m in bands[:-1]])
    triangles = np.concatenate([inverse[m.triangles + o] for (_, m), o in zip(bands, offsets)])
    constraints = [inverse[c + o] for (_, m), o in zip(bands, offsets) for c in m.constraints]
    return Mesh(pos[first], vals[first], triangles, width, height, constraints)

"""Streaming: encode and decode band by band, with memory bounded by the band.

Modelled on python-zstandard's stream objects: `StreamEncoder` takes rows as they come
and writes each band's chunk as soon as the band is complete; `StreamDecoder` yields
decoded rows as each band's chunk arrives.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING, BinaryIO, Callable, Iterator

import numpy as np

from . import container, decoding, integers, lossless_float, residual
from .errors import ATMError, OptionError
from .mesh import Mesh
from .native import _fields

if TYPE_CHECKING:
    from .settings import Settings

# The encoder's modules (codec.pipeline and what it imports, codec.settings,
# codec.representation, codec.slack, codec.holes) are imported by StreamEncoder's
# methods, not here: a process that only decodes never loads them (a first decode
# imported them all, 15 of its 60 ms of imports).


class StreamEncoder:
    """Encode an image arriving in rows to a writable binary file object.

        with codec.StreamEncoder(f, width, height) as enc:
            for rows in source:          # any number of rows at a time
                enc.write(rows)

    The bytes equal `codec.encode(image, band_height=..., **options)` for the same image:
    both code each band with codec.pipeline.code_band; this object only gathers the
    rows of a band. The writer never seeks; at most one band (band_height + 1 rows) is
    held in memory.

    Options (codec.settings.Settings, as keywords or as `settings`): the size knobs
    `points` (target vertex count), or a bound that refinement guarantees on the
    decoded image, per channel: `max_rms`, `max_error` (in sample units), or
    `quality` 1..100 (JPEG-like; an RMS bound, 100 = lossless).

    Float images (dtype float32/float64, one channel) are stored as 16-bit integers with
    a scale and offset: give `value_range=(lowest, highest)` and optionally `precision`
    (the quantisation step). `max_rms`/`max_error` are then in data units and include
    the quantisation error; decoding returns float32. Under `max_error` with
    residual=False and no precision, the step depends on the first band's roughness
    (codec.slack): nothing is written until that band's rows have come.

    progress(rows_done, height) is called after each band is written and, under an error
    bound, after each round of a band's refinement (rows_done then counts the band's
    share done as rows); it watches the work and never changes it, so the bytes are the
    same with or without it.

    channel_axis=True (gray only) records that the image is H x W x 1: it decodes in that
    shape, and `write` takes rows n x W x 1 as well as n x W.
    """

    def __init__(
        self,
        fileobj: BinaryIO,
        width: int,
        height: int,
        *,
        dtype=np.uint8,
        channels: int = 1,
        progress: Callable[[int, int], None] | None = None,
        settings: Settings | None = None,
        channel_axis: bool = False,
        **options,
    ):
        from . import pipeline
        from .settings import Settings

        if settings is None:
            settings = Settings.from_options(**options)
        elif options:
            Settings.from_options(**options)  # names checked, and listed if unknown
            settings = settings.replace(**{k: v for k, v in options.items() if v is not None})
        #: lossless float whose precision 16 bits cannot hold: 32-bit whole numbers of
        #: it in the layer (ATM.md §4.10.1); the mesh's preview gets the finest step
        self._wide = lossless_float.wide_steps(settings)
        if self._wide is not None:
            settings = settings.replace(precision=None)
        self._plan = pipeline.plan(settings, width, height, dtype, channels)
        p = self._plan
        error = residual.layer_bound(settings, p)
        #: lossless float: binary32 keys in the layer (ATM.md §4.10), or (precision
        #: given) exact steps, each written sample checked
        self._exact = residual.exact_floats(settings, p)
        self._check_steps = bool(settings.lossless) and p.dtype.kind == "f" and not self._exact
        storage = lossless_float.KEY_STORAGE if self._exact else p.storage
        self._residual = None if error is None else residual.ResidualEncoder(p.width, p.channels, storage, error)
        # under max_rms the layer's bound is widened from the first band's samples
        # (codec.representation); max_error's, if given too, caps it
        self._rms = None if error is None or p.bound.max_rms is None else (p.bound.max_rms, p.bound.max_error)
        if self._residual is not None:
            self._plan = p = pipeline.plan(residual.mesh_settings(settings, p.width, p.height), width, height, dtype, channels)
        self.width, self.height, self.dtype, self.channels = p.width, p.height, p.dtype, p.channels
        self.band_height = p.band_height
        self._nodata = p.nodata
        self._quant = p.quant
        self._settings, self._fileobj = settings, fileobj
        self._channel_axis = channel_axis and p.channels == 1
        if settings.metadata is not None:
            container.encode_metadata(settings.metadata)  # checked before anything is written
        #: float data under max_error, mesh only: its quantisation (the mesh's slack,
        #: codec.slack) waits for the first band's rows, held here as they came
        self._pending: list[tuple[np.ndarray, np.ndarray]] | None = None
        if self._residual is None and pipeline.needs_roughness(settings, p.dtype):
            self._pending = []
        else:
            self._writer = self._open()
        shape = (self.band_height + 1, p.width) + ((p.channels,) if p.channels > 1 else ())
        self._buf = np.empty(shape, p.storage)
        self._holes = np.zeros(shape[:2], bool)
        if self._exact:
            self._keys = np.empty(shape[:2], lossless_float.KEY_STORAGE)
            self._hole_bits = lossless_float.hole_bits(p.nodata)
            self._unfit = np.zeros(shape[:2], bool)  # valid, but not finite: the preview skips them
        self._filled = 0  # rows of the current band in _buf
        self._y0 = 0  # image row of _buf[0]
        self._received = 0
        self._top: tuple[np.ndarray, np.ndarray] | None = None
        self._step = p.step
        self._closed = False
        self._progress = progress
        #: Totals over the bands written so far (shared-row vertices count in both bands).
        self.bands = self.vertices = self.triangles = 0

    def _open(self) -> container.Writer:
        """Write the header (the plan's quantisation decided) and return the writer."""
        p, settings = self._plan, self._settings
        header = container.Header(
            p.width,
            p.height,
            np.dtype(np.float32) if p.dtype.kind == "f" else p.dtype,
            p.channels,
            quant=p.quant,
            nodata=None if p.nodata is None else float(p.nodata),
            metadata=settings.metadata,
            channel_axis=self._channel_axis,
            exact=self._exact,
            steps=self._wide,
        )
        return container.Writer(self._fileobj, header)

    def _settle(self, pending: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """Plan again with the roughness of the first band (codec.slack), which
        `pending`'s rows (and holes) cover, open the writer, and code those rows."""
        from . import pipeline
        from . import slack as slack_rule

        self._pending = None
        rows, missing = pending[0] if len(pending) == 1 else (
            np.concatenate([r for r, _ in pending]), np.concatenate([m for _, m in pending]))
        first, gone = rows[: len(self._buf)], missing[: len(self._buf)]
        if self._nodata is not None and not np.isnan(self._nodata):
            gone = gone | (first == self._nodata)
        rough = slack_rule.roughness(first, gone)
        p = self._plan
        self._plan = pipeline.plan(self._settings, p.width, p.height, p.dtype, p.channels, roughness=rough)
        self._quant = self._plan.quant
        self._writer = self._open()
        self._take(rows, missing)

    def write(self, rows, holes=None) -> None:
        """Add rows (an n x W, or n x W x 3, array; a single row may be 1-D).

        Pixels without data are those equal to `nodata`, NaN or infinite ones in float
        data, and those True in `holes` (an n x W boolean array, if given)."""
        if self._closed:
            raise ATMError("write() on a closed StreamEncoder")
        rows = np.asarray(rows)
        if self._channel_axis and rows.ndim == 3 and rows.shape[2:] == (1,):
            rows = rows[:, :, 0]
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
        if self._pending is not None:
            held = sum(len(r) for r, _ in self._pending) + len(rows)
            if held > self.height:
                raise ATMError(f"more than the {self.height} rows declared")
            if held >= len(self._buf) or held == self.height:
                self._settle(self._pending + [(rows, missing)])
            else:
                self._pending.append((rows.copy(), missing))  # the caller may reuse its array
            return
        self._take(rows, missing)

    def _take(self, rows: np.ndarray, missing: np.ndarray) -> None:
        """Quantise checked rows (`missing`: the holes given with them) into the band
        buffer, coding each band as it fills."""
        unfit = keys = None
        if self._exact:
            # holes are the pixels with the hole value's very bits (so -0.0 is no hole of
            # 0.0, nor one NaN of another); every other sample is kept as it is
            floats = lossless_float.as_binary32(rows)
            missing |= floats.view(np.uint32) == self._hole_bits
            keys, unfit = lossless_float.keys(floats), ~np.isfinite(floats) & ~missing
            if self._wide is not None:
                keys = self._wide_steps(floats, missing)
            lo, hi = self._quant.offset, self._quant.top
            # NaNs out before widening (a signalling NaN would raise the invalid flag)
            finite = np.where(missing | unfit, np.float32(0), floats).astype(np.float64)
            rows = self._quant.quantise(np.clip(np.where(missing | unfit, lo, finite), lo, hi))
        elif self._quant is not None:
            if self._nodata is not None and not np.isnan(self._nodata):
                missing |= rows == self._nodata
            missing |= ~np.isfinite(rows)
            exact = rows
            # a binary64 offset (an exact step's grid point need not be a binary32)
            rows = self._quant.quantise(np.where(missing, np.float64(self._quant.offset), rows))
            if self._check_steps:
                lossless_float.check_steps(exact, rows, missing, self._quant, self._received)
        elif self._nodata is not None and not np.isnan(self._nodata):
            equal = rows == self._nodata
            missing |= equal if equal.ndim == 2 else equal.all(axis=2)
        if missing.any() and self._nodata is None:
            raise ATMError("the image has holes: give nodata= (the value hole pixels decode to)")
        if self._received + len(rows) > self.height:
            raise ATMError(f"more than the {self.height} rows declared")
        i = 0
        while i < len(rows):
            n = min(len(rows) - i, len(self._buf) - self._filled)
            self._buf[self._filled : self._filled + n] = rows[i : i + n]
            self._holes[self._filled : self._filled + n] = missing[i : i + n]
            if self._exact:
                self._keys[self._filled : self._filled + n] = keys[i : i + n]
                self._unfit[self._filled : self._filled + n] = unfit[i : i + n]
            self._filled += n
            self._received += n
            i += n
            if self._filled == len(self._buf) or self._received == self.height:
                self._flush()

    def _wide_steps(self, floats: np.ndarray, holes: np.ndarray) -> np.ndarray:
        """The whole numbers of the STEP chunk's step of rows (ATM.md §4.10.1), every
        valid sample checked to decode to its own bits."""
        w = self._wide
        q = np.rint((np.where(holes, np.float32(w.offset), floats).astype(np.float64) - w.offset) / w.scale)
        q = np.clip(q, 0, lossless_float.WIDE_LEVELS).astype(lossless_float.KEY_STORAGE)
        lossless_float.check_steps(floats, q, holes, w, self._received)
        return q

    def _flush(self) -> None:
        from . import holes as hole_stage
        from . import pipeline, representation

        if self._filled < 2 and self.height > 1:
            return  # only the shared row of a band already written
        band_holes = self._holes[: self._filled]
        band = self._buf[: self._filled]
        mesh_holes = band_holes if band_holes.any() else None
        if self._exact and self._unfit[: self._filled].any():
            band, mesh_holes = hole_stage.fill(band, band_holes | self._unfit[: self._filled]), None
        if self._residual is not None and mesh_holes is not None:
            # the layer gives the pixels: a mesh of the holes filled need not trace
            # their outlines (what made `points` balloon on range data with holes)
            band, mesh_holes = hole_stage.fill(band, band_holes), None
        coded = pipeline.code_band(
            band,
            mesh_holes,
            self._plan,
            y0=self._y0,
            top=self._top,
            last=self._received == self.height,
            step=self._step,
            progress=None if self._progress is None else self._within_band,
        )
        layer = None
        if self._rms is not None:
            # the layer's bound under max_rms, widened from this first band (codec.representation)
            max_rms, cap = self._rms
            p = self._plan
            n = residual.covered_rows(self._filled, self._received == self.height)
            error, predictor = representation.layer_under_rms(
                self._buf[:n], band_holes[:n] if band_holes.any() else None, p.channels, p.storage, max_rms,
                (self.height - n) * p.width, None if cap is None else int(cap // 1),
            )
            self._residual = residual.ResidualEncoder(p.width, p.channels, p.storage, error, (predictor,))
            self._rms = None
        if self._residual is not None:
            n = residual.covered_rows(self._filled, self._received == self.height)
            coded_rows = self._keys[:n] if self._exact else self._buf[:n]
            layer = self._residual.band(self._y0, coded_rows, band_holes[:n] if band_holes.any() else None)
            self._residual.predictors = residual.PREDICTORS  # later bands' samples are counted at E: either
            if band_holes.any():
                coded.mesh.holes = band_holes.copy()  # for the band's MASK chunk
        self._writer.write_band(coded.y0, coded.mesh, coded.step, coded.delaunay, coded.layout, layer)
        self.bands += 1
        self.vertices += len(coded.mesh.vertices)
        self.triangles += len(coded.mesh.triangles)
        self._top, self._step = coded.bottom_row(), coded.step
        self._buf[0] = self._buf[self._filled - 1]
        self._holes[0] = self._holes[self._filled - 1]
        if self._exact:
            self._keys[0], self._unfit[0] = self._keys[self._filled - 1], self._unfit[self._filled - 1]
        self._y0 += self._filled - 1
        self._filled = 1
        if self._progress is not None:
            self._progress(self._y0 + 1, self.height)

    def _within_band(self, done: float) -> None:
        """Progress inside the band being coded: its share `done` of the band's rows."""
        self._progress(self._y0 + 1 + int(done * (self._filled - 1)), self.height)

    def close(self) -> None:
        """Finish the file. Raises ATMError if fewer rows came than were declared."""
        if self._closed:
            return
        got = self._received + sum(len(r) for r, _ in self._pending or [])
        if got != self.height:
            raise ATMError(f"the stream got {got} of the {self.height} rows declared")
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
        check_backend(backend)
        self._start(container.Reader(fileobj), backend)

    def _start(self, reader: container.Reader, backend: str) -> None:
        """Take the header from a reader that has read it (codec.Decoder makes its own
        reader, with the decompressor and triangulation it owns)."""
        self._reader = reader
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
        return self.rows()

    def rows(self, group_pixels: int = 0) -> Iterator[tuple[int, np.ndarray]]:
        """Iterate as the decoder does (each band's rows as soon as its chunk has
        arrived), or with group_pixels > 0, render consecutive bands together up to
        that many pixels: fewer, larger renders, so that a render's fixed cost (the GL
        backend's framebuffer and read-backs, about 2 ms) falls on many rows of a file
        of small bands; rows then come a group at a time, memory bounded by the group.
        A whole-file decode wants that (codec.decode uses GROUP_PIXELS)."""
        group: list[tuple[int, Mesh]] = []
        pixels = 0
        layer = None
        try:
            for y0, mesh in self._reader:
                self.metadata.update(self._reader.header.metadata or {})
                if self._reader.band_residual is not None:
                    # the residual layer gives every pixel the band emits (ATM.md §4.8),
                    # band after band with the coder's state carried over: no render
                    if group:
                        yield self._rows(group)
                        group, pixels = [], 0
                    if layer is None:
                        h = self._reader.header
                        layer = residual.ResidualDecoder(h.width, h.channels, h.layer_storage)
                    yield self._layered_rows(layer, y0, mesh)
                    continue
                size = mesh.width * mesh.height
                # a band without triangles (a one-pixel-wide image) is rendered alone
                if group and (pixels + size > group_pixels or not len(mesh.triangles)
                              or not len(group[-1][1].triangles)):
                    yield self._rows(group)
                    group, pixels = [], 0
                group.append((y0, mesh))
                pixels += size
        except ATMError:
            if group:  # the intact bands before the damage
                yield self._rows(group)
            raise
        if group:
            yield self._rows(group)

    #: codec.decode(out=)'s array when it is C-contiguous in the rendered image's shape
    #: (H x W, or H x W x C): a group that is the whole image, its samples the image's
    #: own (no scale, offset or holes), is rendered straight into it, not copied there
    _into: np.ndarray | None = None

    def _rows(self, group: list[tuple[int, Mesh]]) -> tuple[int, np.ndarray]:
        """(y0, rows) of a group of consecutive bands: each row once, the group's last
        row only if it is the image's."""
        y0, mesh = group[0][0], stack_bands(group)
        h = self._reader.header
        into = self._into if (self._into is not None and y0 == 0 and mesh.height == self.height
                              and mesh.holes is None and h.quant is None and not h.exact
                              and self._backend == "cpu") else None
        # the Reader's bands passed mesh.validate, so each tiles its rows, and so does
        # their stack: the renderer need not count each row's spans
        return self._finish(y0, mesh, decoding.render(mesh, backend=self._backend, tiles=True, out=into))

    def _layered_rows(self, layer: "residual.ResidualDecoder", y0: int, mesh: Mesh) -> tuple[int, np.ndarray]:
        """(y0, rows) of a band with a residual layer, which gives every row it emits."""
        payload, offset = self._reader.band_residual
        last = y0 + mesh.height == self.height
        rows = layer.band(payload, y0, residual.covered_rows(mesh.height, last), mesh.holes,
                          f"RESD chunk at byte {offset}")
        return self._finish(y0, mesh, rows)

    def _finish(self, y0: int, mesh: Mesh, rows: np.ndarray) -> tuple[int, np.ndarray]:
        """Stored samples -> the image's (dequantised, holes, channel axis), each row once."""
        quant, nodata = self._reader.header.quant, self._reader.header.nodata
        if self._reader.header.exact:
            steps = self._reader.header.steps
            rows = lossless_float.floats(rows) if steps is None else steps.dequantise(rows)
            if mesh.holes is not None:
                # the hole value's exact bits (a NaN's payload too, ATM.md §4.10)
                _fill(rows, mesh.holes[: len(rows)], int(lossless_float.hole_bits(nodata)))
        elif quant is not None and integers.is_signed(self.dtype):
            rows = integers.restore(rows, quant, self.dtype)
        elif quant is not None:
            rows = quant.dequantise(rows)
        if mesh.holes is not None and not self._reader.header.exact:
            # nodata is a sample of the image's type (the reader checked NDAT)
            _fill(rows, mesh.holes[: len(rows)], int(np.array(nodata, rows.dtype).view(_BITS[rows.dtype.itemsize])))
        if len(self.shape) > rows.ndim:  # a gray image with its channel axis (ATM.md §4.9)
            rows = rows[:, :, None]
        last = y0 + mesh.height == self.height
        # the last row is the next band's first: emit it once, from there (a residual
        # layer already leaves it out)
        return y0, rows if last or len(rows) < mesh.height else rows[:-1]


def check_backend(backend: str) -> None:
    """OptionError unless `backend` names a decoder backend."""
    if backend not in decoding.BACKENDS:
        raise OptionError(
            f"unknown decoder backend {backend!r}; choose one of {', '.join(decoding.BACKENDS)}"
        )


#: The unsigned type of each sample width (index: bytes a sample): holes are filled with
#: the nodata value's bits.
_BITS = (None, np.uint8, np.uint16, None, np.uint32)


def _fill(rows: np.ndarray, holes: np.ndarray, bits: int) -> None:
    """rows[holes] = the sample whose bits are `bits`, in every channel (one compiled
    pass without a branch per pixel)."""
    if not rows.flags.c_contiguous:  # not a decoder's own rows
        rows.view(_BITS[rows.dtype.itemsize])[holes] = bits
        return
    pixels = rows.view(_BITS[rows.dtype.itemsize]).reshape(holes.size, -1)
    _fields.fill_holes(pixels, np.ascontiguousarray(holes).reshape(-1).view(np.uint8), bits)


#: Most pixels of the consecutive bands a whole-file decode renders in one call.
GROUP_PIXELS = 1 << 16


def stack_bands(group: list[tuple[int, Mesh]]) -> Mesh:
    """One mesh of consecutive bands, to render at once: their vertices and triangles
    side by side, not merged. Rendering it gives each band's rows as rendering the
    band alone does: a shared row belongs to the triangles of the band below (those
    whose top row it is, ATM.md's ownership rule), which see only their own band's
    vertices, and the rule's arithmetic does not change when a band moves down. Holes:
    each band's, its shared last row from the band below."""
    if len(group) == 1:
        return group[0][1]
    top = group[0][0]
    meshes = [m for _, m in group]
    # one compiled pass (numpy's add and concatenate per band cost more than the copy)
    vertices, triangles = _fields.stack_bands(
        [np.ascontiguousarray(m.vertices, dtype=np.int64) for m in meshes],
        [np.ascontiguousarray(m.triangles, dtype=np.int64) for m in meshes],
        np.array([y0 - top for y0, _ in group], dtype=np.int64))
    holes = None
    if any(m.holes is not None for m in meshes):
        holes = np.concatenate(
            [m.holes[:-1] if m.holes is not None else np.zeros((m.height - 1, m.width), bool) for m in meshes[:-1]]
            + [meshes[-1].holes if meshes[-1].holes is not None else np.zeros((meshes[-1].height, meshes[-1].width), bool)]
        )
    height = group[-1][0] + meshes[-1].height - top
    return Mesh(vertices, np.concatenate([m.values for m in meshes]), triangles, meshes[0].width, height, [], holes)


def decode_all(fileobj: BinaryIO, backend: str = "cpu") -> tuple[np.ndarray, dict]:
    """Decode a whole file into one array; also return its metadata."""
    dec = StreamDecoder(fileobj, backend=backend)
    out = np.empty(dec.shape, dec.dtype)
    for y0, rows in dec.rows(GROUP_PIXELS):
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


def decode_into(dec, out: np.ndarray | None) -> np.ndarray:
    """Decode a StreamDecoder's bands into `out` (checked first) or a new array."""
    shape, dtype = tuple(dec.shape), np.dtype(dec.dtype)
    groups = dec.rows(GROUP_PIXELS)  # small bands rendered a group at a time
    if out is None:
        first = next(groups, None)
        second = next(groups, None) if first is not None else None
        if second is None and first is not None and first[0] == 0 and _whole(first[1], shape, dtype):
            # one render gave the whole image (a file of one band): it is the result,
            # without an image to allocate and copy it into
            return first[1]
        groups = itertools.chain([g for g in (first, second) if g is not None], groups)
        image = np.empty(shape, dtype)
        target = image[..., 0] if dec.channels == 1 and image.ndim == 3 else image
    else:
        if not isinstance(out, np.ndarray):
            raise ATMError(f"out must be a numpy array, not {type(out).__name__}")
        gray = shape[:2]
        shapes = (gray, gray + (1,)) if dec.channels == 1 else (shape,)
        if out.shape not in shapes or out.dtype != dtype:
            want = " or ".join(str(s) for s in shapes)
            raise ATMError(
                f"out is a {out.shape} {out.dtype} array; this image needs shape {want}, dtype {dtype} "
                f"(e.g. numpy.empty({shape}, numpy.{dtype}))"
            )
        if not out.flags.writeable:
            raise ATMError("out is read-only; pass a writeable array")
        # a view, whatever the strides: the gray image fills the one channel in place
        target = out[..., 0] if dec.channels == 1 and out.ndim == 3 else out
        if target.flags.c_contiguous:
            dec._into = target  # a whole-image render may land there itself
    for y0, rows in groups:
        if np.may_share_memory(rows, target):
            continue  # rendered in place (StreamDecoder._into)
        target[y0 : y0 + len(rows)] = rows[..., 0] if rows.ndim > target.ndim else rows
    return out if out is not None else image


def _whole(rows: np.ndarray, shape: tuple, dtype: np.dtype) -> bool:
    """Whether rows, as the decoder made them (no other reference to their memory),
    can be the decoded image itself."""
    flags = rows.flags
    return rows.shape == shape and rows.dtype == dtype and flags.c_contiguous and flags.writeable and flags.owndata

"""Context-coded hole masks (ATM.md §4.11, the HOLE chunk, codec.holemask and
codec._mask): exact round trips, the reference decoder's independent reading, the
writer's choice between HOLE and MASK, and malformed chunks refused with CorruptError."""

from __future__ import annotations

import io
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec import holemask
from codec.errors import ATMError, CorruptError
from codec.format_spec import reference_decoder as ref
from codec.format_spec import schema
from codec.native import _mask
from tests.conftest import chunks
from tests.synthetic import range_scene
from tests.test_residual import _rebuild as rebuild


def _ragged(h: int, w: int, seed: int) -> np.ndarray:
    """A sensor-like mask: dropouts along depth edges and speckle, as kinect and tum have."""
    import cv2

    rng = np.random.default_rng(seed)
    depth = range_scene(w, h, seed=seed, dtype=np.uint16).astype(np.float64)
    edges = cv2.Canny(cv2.convertScaleAbs(depth, alpha=255 / max(depth.max(), 1)), 20, 60) > 0
    edges = cv2.dilate(edges.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    return (edges & (rng.random((h, w)) < 0.7)) | (rng.random((h, w)) < 0.03)


def _kinds(data: bytes) -> list[bytes]:
    return [t for _, t, _ in chunks(data)]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(h=st.integers(1, 40), w=st.integers(1, 40), share=st.sampled_from([0.0, 0.02, 0.3, 0.7, 1.0]),
       seed=st.integers(0, 2**16))
def test_masks_round_trip_and_the_reference_decoder_reads_them(h, w, share, seed):
    holes = np.random.default_rng(seed).random((h, w)) < share
    top = 3 if h > 1 else 0  # a band has two rows or more, unless the image has one
    payload = holemask.encode(top, holes)
    assert np.array_equal(holemask.decode(payload, "HOLE", top, w, top + h), holes)
    y0, rows, back = ref.parse_hole(payload, ref.Header(w, top + h, 0, 1))
    assert (y0, rows) == (top, h) and np.array_equal(back, holes)


#: The template of ATM.md §4.11, as (rows up, columns right) of the pixel coded.
TEMPLATE = [(0, -1), (0, -2), (0, -3), (0, -4), (1, -2), (1, -1), (1, 0), (1, 1), (1, 2), (2, -1), (2, 0), (2, 1)]


@pytest.mark.parametrize("up, right", TEMPLATE)
def test_context_uses_every_template_pixel(up, right):
    # each pixel a copy of one template neighbour (random where that one lies outside):
    # a model that sees the neighbour codes it in a fraction of noise's bytes, one
    # that does not (a template missing that pixel) cannot
    rng = np.random.default_rng(up * 10 + right + 40)
    h, w = 96, 96
    holes = rng.random((h, w)) < 0.5
    for y in range(up, h):
        for x in range(w):
            if 0 <= x + right < w and (up or x + right >= 0):
                holes[y, x] = holes[y - up, x + right]
    payload = holemask.encode(0, holes)
    assert len(payload) < 0.35 * h * w / 8, len(payload)
    assert np.array_equal(ref.parse_hole(payload, ref.Header(w, h, 0, 1))[2], holes)
    shuffled = rng.permutation(holes.ravel()).reshape(h, w)
    assert len(holemask.encode(0, shuffled)) > 0.9 * h * w / 8


def test_ragged_holes_take_the_hole_chunk_and_fewer_bytes():
    image = range_scene(160, 120, seed=3, dtype=np.uint16)
    holes = _ragged(120, 160, 3)
    image[holes] = 0
    data = codec.encode(image, max_error=40, nodata=0)
    assert holemask.CHUNK in _kinds(data) and schema.MASK not in _kinds(data)
    hole_bytes = sum(len(p) for _, t, p in chunks(data) if t == holemask.CHUNK)
    from codec import coding, frames

    runs = coding.runs(holes)
    zstd_runs = len(frames.compress(schema.MaskPayload.build(
        dict(y0=0, rows=120, run_count=len(runs), runs=coding.varints(runs)))))
    assert hole_bytes < 0.85 * zstd_runs, (hole_bytes, zstd_runs)  # kinect, tum: about half
    out = codec.decode(data)
    assert np.array_equal(out == 0, holes | (image == 0))
    assert np.array_equal(ref.decode(data), out)


def test_compact_voids_keep_the_mask_chunk_and_files_mix_them():
    # a DEM void: a few runs, which zstd codes in fewer bytes than the context coder
    dem = range_scene(256, 192, seed=5, dtype=np.uint16)
    dem[dem == 0] = 1
    dem[10:20, 30:50] = 0
    dem[96:111, 128:137] = 0
    data = codec.encode(dem, max_error=2000, nodata=0)
    assert schema.MASK in _kinds(data) and holemask.CHUNK not in _kinds(data)
    # ragged rows above, a clean band below: HOLE then MASK, one file
    mixed = range_scene(40, 30, seed=16, dtype=np.uint16)
    mixed[mixed == 0] = 1
    mixed[:18][np.random.default_rng(16).random((18, 40)) < 0.25] = 0
    data = codec.encode(mixed, nodata=0, band_height=12, points=120, mesher="uniform")
    kinds = [t for t in _kinds(data) if t in (schema.MASK, holemask.CHUNK)]
    assert kinds[0] == holemask.CHUNK and kinds[-1] == schema.MASK
    assert codec.info(data)["bands"] == 3  # the count fields are read past either chunk
    assert np.array_equal(codec.decode(data), ref.decode(data))
    assert np.array_equal(codec.decode(data) == 0, mixed == 0)


def _rebuild(data: bytes, change) -> bytes:
    """The file with its first HOLE chunk's payload passed through change (None: the
    chunk is dropped), CRCs recomputed."""
    seen = []

    def first(ctype, payload):
        if ctype == holemask.CHUNK and not seen:
            seen.append(1)
            return change(payload)
        return ctype, payload

    return rebuild(data, first)


def _holed() -> bytes:
    image = range_scene(48, 36, seed=7, dtype=np.uint16)
    image[_ragged(36, 48, 7)] = 0
    data = codec.encode(image, max_error=30, nodata=0, band_height=12)
    assert holemask.CHUNK in _kinds(data)
    return data


@pytest.mark.parametrize(
    "change",
    [
        lambda p: (holemask.CHUNK, p[:-1]),  # the coded bytes end early
        lambda p: (holemask.CHUNK, p + b"\0"),  # a byte too many
        lambda p: (holemask.CHUNK, p[:5]),  # shorter than its fixed fields
        lambda p: (holemask.CHUNK, p[:8]),  # no coded bytes at all
        lambda p: (holemask.CHUNK, struct.pack("<I", 1) + p[4:]),  # the wrong first row
        lambda p: (holemask.CHUNK, p[:4] + struct.pack("<I", 5) + p[8:]),  # the wrong row count
        lambda p: (holemask.CHUNK, p[:4] + struct.pack("<I", 0xFFFFFFFF) + p[8:]),  # rows beyond the image
        lambda p: None,  # a band without its mask
        lambda p: (schema.MASK, p),  # a HOLE payload under MASK's name
    ],
)
def test_malformed_hole_chunks_are_refused(change):
    bad = _rebuild(_holed(), change)
    with pytest.raises(CorruptError):
        codec.decode(bad)
    with pytest.raises(ref.DecodeError):
        ref.decode(bad)


def test_damaged_coded_bits_never_crash():
    # no CRC inside the payload: flipped bytes decode to another mask (then the shared
    # row or the layer may disagree) or are refused, always as the codec's own error
    data = _holed()
    rng = np.random.default_rng(0)
    for _ in range(200):
        def flip(p):
            b = bytearray(p)
            b[int(rng.integers(8, len(b)))] ^= int(rng.integers(1, 256))
            return holemask.CHUNK, bytes(b)

        try:
            codec.decode(_rebuild(data, flip))
        except ATMError:
            pass


def test_stream_and_gl_decoders_read_hole_chunks(gl):
    data = _holed()
    whole = codec.decode(data)
    streamed = np.concatenate([rows for _, rows in codec.StreamDecoder(io.BytesIO(data))])
    assert np.array_equal(streamed[: len(whole)], whole)
    layered_free = codec.encode(codec.decode(data), nodata=0, points=300)  # a mesh-only file: GL renders it
    assert holemask.CHUNK in _kinds(layered_free)
    assert np.array_equal(codec.decode(layered_free, backend="gl"), codec.decode(layered_free))


def test_kernel_decodes_a_512_mask_it_wrote():
    holes = np.ascontiguousarray(_ragged(512, 512, 9), np.uint8)
    coded = _mask.encode(holes)
    status, back = _mask.decode(np.frombuffer(coded, np.uint8), 512, 512)
    assert status == _mask.Status.MASK_OK and np.array_equal(back, holes.astype(bool))

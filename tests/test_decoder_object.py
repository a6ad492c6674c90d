"""codec.Decoder: decodes file after file as codec.decode does (pixels, shapes, errors),
in a decompressor and triangulation buffers it owns, one thread at a time."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import codec
from codec import container, triangulate
from tests.synthetic import range_scene


def _files() -> list[bytes]:
    """Files that between them take every decode path: one band and many, 16-bit with
    holes, float, RGB, a residual layer, a gray image with its channel axis."""
    gray = range_scene(96, 80, seed=1)
    rgb = np.stack([gray, gray[::-1], 255 - gray], axis=2)
    depth = (gray.astype(np.uint16) * 200)
    depth[10:20, 30:50] = 0
    floats = gray.astype(np.float32) * 0.01
    floats[40:45, 5:9] = np.nan
    return [
        codec.encode(gray, points=300),
        codec.encode(gray, points=300, band_height=16),
        codec.encode(depth, points=400, nodata=0),
        codec.encode(floats, points=300),
        codec.encode(rgb, points=300),
        codec.encode(gray, max_error=2),
        codec.encode(gray[:, :, None], points=200),
    ]


def test_a_decoder_decodes_file_after_file_as_codec_decode():
    files = _files()
    decoder = codec.Decoder()
    for _ in range(2):  # again, in the memory the first round left
        for data in files:
            want, got = codec.decode(data), decoder.decode(data)
            assert got.shape == want.shape and got.dtype == want.dtype
            assert np.array_equal(got, want, equal_nan=want.dtype.kind == "f")
            out = np.full_like(want, 7)
            assert decoder.decode(data, out=out) is out
            assert np.array_equal(out, want, equal_nan=want.dtype.kind == "f")


def test_a_decoder_reuses_its_own_decompressor_and_triangulation(monkeypatch):
    """Every file's reader takes the decoder's own objects, none made anew; two
    decoders share nothing."""
    seen = []
    made = container.Reader.__init__

    def spy(self, *args, **kwargs):
        made(self, *args, **kwargs)
        seen.append((self._dctx, self._triangulator))

    monkeypatch.setattr(container.Reader, "__init__", spy)
    files = _files()
    first, second = codec.Decoder(), codec.Decoder()
    for data in files:
        first.decode(data)
    second.decode(files[0])
    assert {id(d) for d, _ in seen[:-1]} == {id(first._dctx)}
    assert {id(t) for _, t in seen[:-1]} == {id(first._triangulator)}
    assert seen[-1][0] is second._dctx and seen[-1][1] is second._triangulator
    assert first._dctx is not second._dctx and first._triangulator is not second._triangulator
    assert isinstance(first._triangulator, triangulate.Delaunay)


def test_a_decoder_refuses_what_codec_decode_refuses_and_goes_on():
    """A damaged file gives codec.decode's exception and message, and the decoder
    decodes the next file as if nothing had happened (its triangulation refused
    half-way through, its decompressor stopped on a bad frame)."""
    files = _files()
    decoder = codec.Decoder()
    damaged = []
    for data in files[:3]:
        for at in range(20, len(data) - 12, max(1, len(data) // 40)):
            bad = bytearray(data)
            bad[at] ^= 0x5A
            damaged.append(bytes(bad))
        damaged.append(data[: len(data) // 2])
    for bad in damaged:
        try:
            want = codec.decode(bad)
        except codec.ATMError as exc:
            with pytest.raises(type(exc)) as got:
                decoder.decode(bad)
            assert str(got.value) == str(exc)
        else:
            assert np.array_equal(decoder.decode(bad), want)
        assert np.array_equal(decoder.decode(files[1]), codec.decode(files[1]))


def test_a_decoder_is_used_by_one_thread_at_a_time():
    decoder = codec.Decoder()
    data = _files()[0]
    entered, leave = threading.Event(), threading.Event()
    holder = decoder._triangulator
    run = holder.triangles_and_crc

    def slow(*args, **kwargs):  # holds the decoder inside a decode
        entered.set()
        leave.wait(10)
        return run(*args, **kwargs)

    holder.triangles_and_crc = slow
    with ThreadPoolExecutor(1) as pool:
        busy = pool.submit(decoder.decode, data)
        assert entered.wait(10)
        with pytest.raises(RuntimeError, match="in use by another thread"):
            decoder.decode(data)
        leave.set()
        assert np.array_equal(busy.result(), codec.decode(data))
    holder.triangles_and_crc = run
    assert np.array_equal(decoder.decode(data), codec.decode(data))  # free again


def test_decoders_in_threads_give_the_pixels_one_thread_does():
    files = _files()
    alone = [codec.decode(d) for d in files]

    def work(k: int) -> list[np.ndarray]:
        decoder = codec.Decoder()
        return [decoder.decode(files[(k + i) % len(files)]) for i in range(3 * len(files))]

    with ThreadPoolExecutor(4) as pool:
        for k, images in enumerate(pool.map(work, range(4))):
            for i, image in enumerate(images):
                want = alone[(k + i) % len(files)]
                assert np.array_equal(image, want, equal_nan=want.dtype.kind == "f")


def test_a_decoder_names_a_bad_backend():
    with pytest.raises(codec.OptionError, match="unknown decoder backend 'vulkan'"):
        codec.Decoder(backend="vulkan")


def test_a_decoder_names_a_damaged_frame_as_codec_decode_does_after_a_frame_read_in_part(monkeypatch):
    # a MESH payload over 64 KiB is read in part first (frames.head): a stream read left
    # unfinished in the decoder's own decompressor changed what it said of a later
    # file's damaged frame ("Data corruption detected" for "Destination buffer is too
    # small"), so a Decoder's errors depended on the files before
    from codec import frames
    from codec.format_spec import schema
    from tests.test_hardening import _chunk, _file

    noise = np.random.default_rng(5).integers(0, 256, (200, 300), dtype=np.uint8)
    dense = codec.encode(noise, points=50_000, residual=False)
    heads = []
    real_head = frames.head
    monkeypatch.setattr(frames, "head", lambda *a, **k: heads.append(1) or real_head(*a, **k))
    # a meta chunk's frame whose descriptor byte was damaged (from the fuzzer's mutations)
    damaged = _file(8, 8, _chunk(schema.META, bytes.fromhex("28b52ffd20f1028d0000507b226b223a202261227d010001000005")))
    with pytest.raises(codec.CorruptError) as fresh:
        codec.decode(damaged)
    decoder = codec.Decoder()
    decoder.decode(dense)
    assert heads  # the dense file took the partial read
    with pytest.raises(codec.CorruptError) as reused:
        decoder.decode(damaged)
    assert str(reused.value) == str(fresh.value)


def test_a_process_that_only_decodes_loads_no_encoder_module(tmp_path) -> None:
    """codec.decode, codec.Decoder and a StreamDecoder of every kind of file load none
    of the encoder's modules (codec.pipeline and what only it needs): a first decode
    spent a quarter of its CPU time importing them."""
    import json
    import subprocess
    import sys

    names = []
    for k, data in enumerate(_files()):
        (tmp_path / f"{k}.atm").write_bytes(data)
        names.append(str(tmp_path / f"{k}.atm"))
    encoder = ["codec.pipeline", "codec.settings", "codec.representation", "codec.slack", "codec.holes"]
    code = (
        "import io, json, sys, codec\n"
        f"for name in {names!r}:\n"
        "    data = open(name, 'rb').read()\n"
        "    codec.decode(data)\n"
        "    codec.Decoder().decode(data)\n"
        "    list(codec.StreamDecoder(io.BytesIO(data)))\n"
        f"print(json.dumps([m for m in {encoder!r} if m in sys.modules]))\n"
    )
    # from the files' folder: the child imports the installed codec (under
    # fuzz/asan.sh, the instrumented one, not the copy's uncompiled sources)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path)
    assert json.loads(out.stdout) == []

"""codec.Decoder: decode file after file in working memory the decoder owns."""

from __future__ import annotations

import io
import threading

import numpy as np

from . import container, frames
from .buffers import as_bytes
from .stream import StreamDecoder, check_backend, decode_into
from .triangulate import Delaunay


class Decoder:
    """Decodes .atm data again and again, as `codec.decode` does (the same pixels, the
    same errors), reusing what a decode would otherwise make anew: a zstd decompressor
    and the triangulation's working buffers. Like zstandard's ZstdDecompressor, for
    whoever decodes many files (a server, a data loader): keep one per thread.

        decoder = codec.Decoder()
        for data in files:
            image = decoder.decode(data)

    A decode's memory that outlives it is what lets the next one skip the allocation
    and the page faults of fresh memory: 14 % of a 512² decode's CPU time in a process
    that decodes only such files, 3-4 % in benchmarks/speed.py's, whose other codecs'
    larger allocations keep glibc from handing the memory back between decodes. The
    price: the decoder keeps the triangulation buffers of the largest band it has
    decoded until it is dropped.
    One thread at a time: a call while another thread's is running raises RuntimeError.
    """

    def __init__(self, *, backend: str = "cpu") -> None:
        """backend: as for codec.decode ("cpu" or "gl")."""
        check_backend(backend)
        self.backend = backend
        self._dctx = frames.decompressor()
        self._triangulator = Delaunay()
        self._busy = threading.Lock()

    def decode(self, data, *, out: np.ndarray | None = None) -> np.ndarray:
        """codec.decode(data, out=out, backend=self.backend), in this decoder's memory."""
        if not self._busy.acquire(blocking=False):
            raise RuntimeError("codec.Decoder.decode: the decoder is in use by another thread (keep one per thread)")
        try:
            reader = container.Reader(io.BytesIO(as_bytes(data)), dctx=self._dctx, triangulator=self._triangulator)
            dec = StreamDecoder.__new__(StreamDecoder)
            dec._start(reader, self.backend)
            return decode_into(dec, out)
        finally:
            self._busy.release()

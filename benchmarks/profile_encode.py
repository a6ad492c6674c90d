"""Encoder work and output: triangulations, encode time and a fingerprint of the bytes.

    python benchmarks/profile_encode.py [--hash] [--profile N] [--repeat 3]

* calls: how many triangulations `codec.encode` makes while it encodes camera as one
  band, as 16 bands, and at an error bound (quality=50): calls of codec's own
  `codec.triangulate.triangulate`, counted by wrapping it in every codec module that
  holds it (so the count does not depend on the library behind it), and the rounds of
  an incremental `codec.triangulate.Triangulation` (each `triangles()` it gives out;
  the time of all its calls counts as triangulating).
* time: each encode as a ratio to its peer in the same round, a JPEG encode of
  camera (cv2.imencode, quality 90), and the share of it spent triangulating; the
  medians over `--repeat` interleaved rounds.
* --hash: SHA-256 over the bytes of every corpus encode the regression cases cover
  (each image at 1 % and 2.8 % vertex density, camera in 16 bands, camera at
  quality 50, the disparity map with its holes as float data), and over their
  decodes: a refactoring that keeps both digests keeps the files and the pixels.
* --profile N: the N costliest functions (cumulative time) of one camera encode.

Measures and prints; asserts nothing.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import importlib
import pstats
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

import codec  # noqa: E402
import codec.triangulate  # noqa: E402
from tests.corpus import disparity_raw, load_corpus  # noqa: E402

DENSITIES = (0.01, 0.028)


class TriangleCounter:
    """Counts (and times) the calls of codec.triangulate.triangulate while installed,
    wherever codec imported it by name, and the rounds of codec.triangulate.Triangulation
    (its triangles() calls; all its methods timed)."""

    TIMED = ("__init__", "insert", "constrain", "triangles")

    def __init__(self) -> None:
        self.calls = 0
        self.seconds = 0.0
        self._real = codec.triangulate.triangulate
        self._holders: list = []
        self._methods: dict = {}

    def __enter__(self) -> "TriangleCounter":
        def counted(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return self._real(*args, **kwargs)
            finally:
                self.calls += 1
                self.seconds += time.perf_counter() - t0

        for name in ("codec.pipeline", "codec.meshcode", "codec.mesher.adaptive", "codec.mesher.uniform"):
            importlib.import_module(name)  # the meshers are imported on first use
        self._holders = [
            m for name, m in list(sys.modules.items())
            if name.startswith("codec") and getattr(m, "triangulate", None) is self._real
        ]
        for m in self._holders:
            m.triangulate = counted
        incremental = codec.triangulate.Triangulation
        self._methods = {name: getattr(incremental, name) for name in self.TIMED}
        for name, method in self._methods.items():
            setattr(incremental, name, self._timed(method, name == "triangles"))
        return self

    def _timed(self, method, counts: bool):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self.calls += counts
                self.seconds += time.perf_counter() - t0

        return timed

    def __exit__(self, *exc) -> None:
        for m in self._holders:
            m.triangulate = self._real
        for name, method in self._methods.items():
            setattr(codec.triangulate.Triangulation, name, method)


def cases(images: dict[str, np.ndarray]):
    """(name, image, options) of every encode the fingerprint covers."""
    for name, image in images.items():
        for density in DENSITIES:
            yield f"{name}@{density}", image, {"points": round(density * image.size)}
    camera = images["camera"]
    yield "camera/16 bands", camera, {"points": round(0.028 * camera.size), "band_height": 32}
    yield "camera q50", camera, {"quality": 50}
    disp = disparity_raw().astype(np.float32)
    yield "disparity float", disp, {"points": round(0.01 * disp.size)}


def fingerprint(images: dict[str, np.ndarray]) -> tuple[str, str]:
    """SHA-256 over all the cases' bytes and over their decodes; prints each case's
    size and the start of its own digest, to find a change."""
    enc, dec = hashlib.sha256(), hashlib.sha256()
    for name, image, options in cases(images):
        data = codec.encode(image, **options)
        enc.update(data)
        dec.update(np.ascontiguousarray(codec.decode(data)).tobytes())
        print(f"  {name:<22} {len(data):>7} bytes  {hashlib.sha256(data).hexdigest()[:12]}")
    return enc.hexdigest(), dec.hexdigest()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed rounds")
    parser.add_argument("--hash", action="store_true", help="fingerprint the corpus encodes")
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="top N functions of a camera encode")
    args = parser.parse_args(argv)
    images = load_corpus()
    camera = images["camera"]
    runs = {
        "camera, 1 band": dict(points=round(0.028 * camera.size)),
        "camera, 16 bands": dict(points=round(0.028 * camera.size), band_height=32),
        "camera, quality 50": dict(quality=50),
    }
    import cv2

    print(f"{'encode':<20} {'triangulations':>14} {'time / JPEG':>12} {'triangulating':>13}")
    ratio: dict[str, list[float]] = {name: [] for name in runs}
    share: dict[str, list[float]] = {name: [] for name in runs}
    counts: dict[str, int] = {}
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        cv2.imencode(".jpg", camera, [cv2.IMWRITE_JPEG_QUALITY, 90])
        jpeg = time.perf_counter() - t0
        for name, options in runs.items():
            with TriangleCounter() as counter:
                t0 = time.perf_counter()
                codec.encode(camera, **options)
                total = time.perf_counter() - t0
            counts[name] = counter.calls
            ratio[name].append(total / jpeg)
            share[name].append(counter.seconds / total)
    for name in runs:
        print(
            f"{name:<20} {counts[name]:>14} {statistics.median(ratio[name]):>11.0f}x "
            f"{statistics.median(share[name]):>12.0%}"
        )
    if args.profile:
        prof = cProfile.Profile()
        prof.runcall(codec.encode, camera, points=round(0.028 * camera.size))
        pstats.Stats(prof).sort_stats("cumulative").print_stats(args.profile)
    if args.hash:
        enc, dec = fingerprint(images)
        print(f"SHA-256 of the corpus encodes: {enc}\nSHA-256 of their decodes:      {dec}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

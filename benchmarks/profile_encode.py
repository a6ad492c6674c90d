"""Encoder work and output: triangulations, encode time and a fingerprint of the bytes.

    python benchmarks/profile_encode.py [--hash] [--profile N] [--repeat 3] [--stages N [--sides ...]]

* calls: how many triangulations `codec.encode` makes while it encodes camera as one
  band, as 16 bands, and at an error bound (quality=50): calls of codec's own
  `codec.triangulate.triangulate`, counted by wrapping it in every codec module that
  holds it (so the count does not depend on the library behind it), and the rounds of
  an incremental `codec.triangulate.Triangulation` (each `triangles()` it gives out,
  or `dirty()` where refinement keeps it by slot; the time of all its calls counts as
  triangulating).
* time: each encode as a ratio to its peer in the same round, a JPEG encode of
  camera (cv2.imencode, quality 90), and the share of it spent triangulating; the
  medians over `--repeat` interleaved rounds.
* --hash: SHA-256 over the bytes of every corpus encode the regression cases cover
  (each image at 1 % and 2.8 % vertex density, camera in 16 bands, camera at
  quality 50, the disparity map with its holes as float data), and over their
  decodes: a refactoring that keeps both digests keeps the files and the pixels.
* --profile N: the N costliest functions (cumulative time) of one camera encode.
* --stages N [--sides 512 2048]: only the CPU budget of the encoder's stages (STAGES),
  ms per encode over N encodes of camera and astronaut at 2.8 % vertices, at each side
  (cubic resizes).

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


def _timed(function, clock, add):
    """`function` wrapped to hand add() the `clock` time of each call."""
    def timed(*args, **kwargs):
        t0 = clock()
        try:
            return function(*args, **kwargs)
        finally:
            add(clock() - t0)

    return timed


class TriangleCounter:
    """Counts (and times) the calls of codec.triangulate.triangulate while installed,
    wherever codec imported it by name, and the rounds of codec.triangulate.Triangulation
    (its triangles() calls, or dirty() where refinement keeps it by slot; all its
    methods timed)."""

    TIMED = ("__init__", "insert", "constrain", "triangles", "dirty", "slots")

    def __init__(self) -> None:
        self.calls = 0
        self.seconds = 0.0
        self._real = codec.triangulate.triangulate
        self._holders: list = []
        self._methods: dict = {}

    def __enter__(self) -> "TriangleCounter":
        counted = self._timed(self._real, True)
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
            setattr(incremental, name, self._timed(method, name in ("triangles", "dirty")))
        return self

    def _timed(self, method, counts: bool):
        def add(seconds: float) -> None:
            self.calls += counts
            self.seconds += seconds

        return _timed(method, time.perf_counter, add)

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


#: The encoder's stages the --stages budget times: (module, name where the encoder
#: looks it up) pairs, front to writing; a stage's time includes any of these it calls
#: (write_band's includes encode_band and compress_parts).
STAGES = (
    ("codec.mesher.edges", "detect"), ("codec.mesher.adaptive", "_off_edge_curvature"),
    ("codec.mesher.polylines", "trace"), ("codec.mesher.adaptive", "_select_lines"),
    ("codec.mesher.adaptive", "unfold"), ("codec.mesher.adaptive", "_excluded"),
    ("codec.mesher.sampling", "curvature"), ("codec.mesher.sampling", "density"),
    ("codec.mesher.sampling", "sample"), ("codec.mesher.adaptive", "refine_to_budget"),
    ("codec.mesher.values", "from_statistics"), ("codec.pipeline", "meshcode.in_stored_order"),
    ("codec.pipeline", "meshcode.layout"), ("codec.pipeline", "meshcode.quantise"),
    ("codec.container", "Writer.write_band"), ("codec.container", "meshcode.encode_band"),
    ("codec.container", "frames.compress_parts"),
)


class StageTimer:
    """Process CPU time (OpenCV's and zstd's threads included) spent in each of STAGES
    while installed, by wrapping each where the encoder looks it up."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._saved: list = []

    def __enter__(self) -> "StageTimer":
        for module, path in STAGES:
            *owner_path, name = path.split(".")
            owner = importlib.import_module(module)
            for part in owner_path:
                owner = getattr(owner, part)
            real = getattr(owner, name)
            self._saved.append((owner, name, real))
            setattr(owner, name, self._timed(real, name))
        return self

    def _timed(self, real, name: str):
        def add(seconds: float) -> None:
            self.seconds[name] = self.seconds.get(name, 0.0) + seconds

        return _timed(real, time.process_time, add)

    def __exit__(self, *exc) -> None:
        for owner, name, real in reversed(self._saved):
            setattr(owner, name, real)


def stage_budget(images: dict[str, np.ndarray], sides: list[int], encodes: int) -> None:
    """Print the CPU ms per encode of every stage (and of the whole encode) of camera
    and astronaut at 2.8 % vertices, at each side (cubic resizes)."""
    import cv2

    rows = []
    for side in sides:
        for name in ("camera", "astronaut"):
            image = images[name]
            if image.shape != (side, side):
                image = cv2.resize(image, (side, side), interpolation=cv2.INTER_CUBIC)
            points = round(0.028 * image.size)
            codec.encode(image, points=points)  # warm
            with StageTimer() as timer:
                t0 = time.process_time()
                for _ in range(encodes):
                    codec.encode(image, points=points)
                total = time.process_time() - t0
            rows.append((f"{name}@{side}", total / encodes, {k: v / encodes for k, v in timer.seconds.items()}))
    names = [path.split(".")[-1] for _, path in STAGES]
    print(f"{'stage (CPU ms an encode)':<26}" + "".join(f"{label:>16}" for label, _, _ in rows))
    print(f"{'whole encode':<26}" + "".join(f"{total * 1e3:>16.2f}" for _, total, _ in rows))
    for stage in names:
        print(f"{stage:<26}" + "".join(f"{times.get(stage, 0.0) * 1e3:>16.2f}" for _, _, times in rows))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed rounds")
    parser.add_argument("--hash", action="store_true", help="fingerprint the corpus encodes")
    parser.add_argument("--profile", type=int, default=0, metavar="N", help="top N functions of a camera encode")
    parser.add_argument("--stages", type=int, default=0, metavar="N",
                        help="only the CPU budget per stage, over N encodes of camera and astronaut")
    parser.add_argument("--sides", type=int, nargs="+", default=[512, 2048], help="image sides for --stages")
    args = parser.parse_args(argv)
    images = load_corpus()
    if args.stages:
        stage_budget(images, args.sides, args.stages)
        return 0
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

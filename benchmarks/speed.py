"""Decoder speed on the public corpus: .atm CPU and GL decoders against JPEG.

For each image, meshed at 2.8 % vertex density: the median time of codec.decode with
backend="cpu" and backend="gl" (warm context), of the mesh -> image step alone (the
decoders, without container parsing and without rebuilding the triangulation, which
the format leaves implicit: constrained Delaunay through `triangle`), and of
cv2.imdecode of the same image as JPEG quality 90, all in this process. Measures and
prints; asserts nothing.

    python benchmarks/speed.py [--repeat 21]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import codec  # noqa: E402
from codec import decoder_cpu, decoder_gl  # noqa: E402
from codec.errors import BackendError  # noqa: E402

DENSITY = 0.028


def median_ms(fn: Callable[[], object], repeat: int) -> float:
    """Median wall time of fn() in milliseconds, after one warm-up call."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=21, help="timed runs per figure")
    args = parser.parse_args(argv)
    import cv2

    from tests.corpus import load_corpus

    try:
        decoder_gl.context()
        gl = True
    except BackendError as exc:
        print(f"GL decoder unavailable: {exc}")
        gl = False
    rows = []
    for name, img in load_corpus().items():
        h, w = img.shape[:2]
        data = codec.encode(img, points=max(4, round(DENSITY * w * h)))
        mesh = codec.decode_mesh(data)
        ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        jpeg_ms = median_ms(lambda: cv2.imdecode(jpeg, cv2.IMREAD_UNCHANGED), args.repeat)
        cpu_ms = median_ms(lambda: codec.decode(data, backend="cpu"), args.repeat)
        cpu_render = median_ms(lambda: decoder_cpu.render(mesh), args.repeat)
        if gl:
            gl_ms = median_ms(lambda: codec.decode(data, backend="gl"), args.repeat)
            gl_render = median_ms(lambda: decoder_gl.render(mesh), args.repeat)
        else:
            gl_ms = gl_render = float("nan")
        rows.append((name, f"{w}x{h}", len(mesh.triangles), jpeg_ms, cpu_ms, cpu_render,
                     gl_ms, gl_render))
    head = ("image", "size", "triangles", "jpeg ms", "cpu ms", "cpu render", "gl ms",
            "gl render", "cpu/jpeg", "cpu render/jpeg", "gl/jpeg", "gl render/jpeg")
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---" for _ in head) + "|")
    for name, size, tris, jpeg_ms, cpu_ms, cpu_r, gl_ms, gl_r in rows:
        print(f"| {name} | {size} | {tris} | {jpeg_ms:.2f} | {cpu_ms:.2f} | {cpu_r:.2f} | "
              f"{gl_ms:.2f} | {gl_r:.2f} | {cpu_ms / jpeg_ms:.1f} | {cpu_r / jpeg_ms:.1f} | "
              f"{gl_ms / jpeg_ms:.1f} | {gl_r / jpeg_ms:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

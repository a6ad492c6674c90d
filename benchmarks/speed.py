"""Decoder speed on the public corpus: .atm CPU and GL decoders against JPEG.

For each image, meshed at 2.8 % vertex density, in this process:

* jpeg: cv2.imdecode of the same image as JPEG quality 90;
* render: the CPU decoder alone (decoder_cpu.render, mesh -> image), and the GL
  decoder alone with a warm context (decoder_gl.render);
* decode: codec.decode of the .atm bytes with backend="cpu" and "gl": container
  parsing, the mesh decoding, the constrained Delaunay triangulation the format leaves
  implicit, validation and the render;
* triangulate: that triangulation alone (codec.triangulate on each band's vertices
  and walls), the part of a whole decode no decoder can skip.

The measurements are interleaved: every round times each of them once, so that a
burst of load on a shared machine hits all of them alike. The table gives the median
time of each and, as the ratios, the median over the rounds of each round's own
ratio to JPEG. Measures and prints; asserts nothing.

    python benchmarks/speed.py [--repeat 31] [--images camera moon]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import codec  # noqa: E402
from codec import container, decoder_cpu, decoder_gl  # noqa: E402
from codec.errors import BackendError  # noqa: E402
from codec.mesh import segments  # noqa: E402
from codec.triangulate import triangulate  # noqa: E402

DENSITY = 0.028


def interleaved(fns: dict[str, Callable[[], object]], repeat: int) -> dict[str, list[float]]:
    """Wall times in milliseconds of each function, `repeat` rounds in which each runs
    once (after one warm-up call each)."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(1e3 * (time.perf_counter() - t0))
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=31, help="timed rounds per image")
    parser.add_argument("--images", nargs="*", help="corpus images to measure (default: all)")
    args = parser.parse_args(argv)
    import cv2

    from tests.corpus import load_corpus

    try:
        decoder_gl.context()
        gl = True
    except BackendError as exc:
        print(f"GL decoder unavailable: {exc}")
        gl = False
    corpus = load_corpus()
    names = args.images or list(corpus)
    unknown = sorted(set(names) - set(corpus))
    if unknown:
        parser.error(f"no corpus image {', '.join(unknown)}; choose from {', '.join(corpus)}")
    cols = ["jpeg", "render", "decode", "triangulate"] + (["gl render", "gl decode"] if gl else [])
    head = ["image", "size", "triangles"] + [f"{c} ms" for c in cols]
    head += [f"{c} / jpeg" for c in cols[1:]]
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---:" if i > 1 else "---" for i in range(len(head))) + "|")
    for name in names:
        img = corpus[name]
        h, w = img.shape[:2]
        data = codec.encode(img, points=max(4, round(DENSITY * w * h)))
        mesh = codec.decode_mesh(data)
        bands = [(m.vertices, segments(m.constraints)) for _, m in container.unpack(data)[1]]
        ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        fns: dict[str, Callable[[], object]] = {
            "jpeg": lambda: cv2.imdecode(jpeg, cv2.IMREAD_UNCHANGED),
            "render": lambda: decoder_cpu.render(mesh),
            "decode": lambda: codec.decode(data, backend="cpu"),
            "triangulate": lambda: [triangulate(v, s) for v, s in bands],
        }
        if gl:
            fns["gl render"] = lambda: decoder_gl.render(mesh)
            fns["gl decode"] = lambda: codec.decode(data, backend="gl")
        times = interleaved(fns, args.repeat)
        medians = [statistics.median(times[c]) for c in cols]
        ratios = [statistics.median(t / j for t, j in zip(times[c], times["jpeg"])) for c in cols[1:]]
        row = [name, f"{w}x{h}", f"{len(mesh.triangles):,}"]
        row += [f"{m:.2f}" for m in medians] + [f"{r:.1f}" for r in ratios]
        print("| " + " | ".join(row) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What the version-6 triangulation rule (format_spec/ATM.md §4.2.5) costs, on the
public corpus at the default vertex density (2.8 %):

* ties: free edges (shared by two triangles, no wall) whose quadrilateral is exactly
  cocircular, as a share of all free edges, for the adaptive (default) and the
  uniform mesher;
* flips: how many the canonical pass makes on Triangle's own triangulation of each
  file's vertices and walls;
* bytes: each file's size with the pass and without it (Triangle's ties kept, as
  version 5 stored them), and the change;
* cost (the --timed images): the canonical pass alone on Triangle's triangulation
  against a whole codec.decode, in interleaved rounds (every round times each once);
  the median time of each and the median over the rounds of each round's ratio.

Measures and prints; asserts nothing.

    python benchmarks/canonical.py [--images camera moon] [--timed camera] [--repeat 31]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
from pathlib import Path
from typing import Iterator

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

import codec  # noqa: E402
from codec import canonical, container  # noqa: E402
from codec import triangulate as triangulate_module  # noqa: E402
from codec.mesh import segments  # noqa: E402
from speed import interleaved  # noqa: E402


@contextlib.contextmanager
def triangle_alone() -> Iterator[None]:
    """Within it, codec.triangulate.by_triangle returns Triangle's triangles unflipped."""
    kept = canonical.canonicalise  # (by_triangle imports it from there at each call)
    canonical.canonicalise = lambda vertices, triangles, constraints: np.asarray(triangles, np.int64)
    try:
        yield
    finally:
        canonical.canonicalise = kept


def bands(data: bytes) -> list[tuple[np.ndarray, np.ndarray | None, np.ndarray]]:
    """(vertices, wall segments, triangles) of each band of a file."""
    return [
        (m.vertices, segments(m.constraints) if m.constraints else None, m.triangles)
        for _, m in container.unpack(data)[1]
    ]


def ties_and_flips(data: bytes) -> tuple[int, int, int]:
    """(free edges, exact ties, flips from Triangle's triangulation) over a file."""
    free = ties = flips = 0
    for v, walls, tris in bands(data):
        f, t = canonical.tie_count(v, tris, walls)
        with triangle_alone():
            raw = triangulate_module.by_triangle(v, walls)
        free, ties, flips = free + f, ties + t, flips + canonical.flip_to_canonical(v, raw, walls)[1]
    return free, ties, flips


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--images", nargs="*", help="corpus images (default: all)")
    parser.add_argument("--timed", nargs="*", default=["camera"], help="images whose pass cost is timed")
    parser.add_argument("--repeat", type=int, default=31, help="timed rounds")
    args = parser.parse_args(argv)
    from tests.corpus import load_corpus

    corpus = load_corpus()
    names = args.images or list(corpus)
    unknown = sorted(set(names + args.timed) - set(corpus))
    if unknown:
        parser.error(f"no corpus image {', '.join(unknown)}; choose from {', '.join(corpus)}")
    head = ["image", "free edges", "ties %", "flips", "uniform free", "uniform ties %",
            "uniform flips", "bytes v5 rule", "bytes v6", "change %"]
    print("| " + " | ".join(head) + " |")
    print("|---|" + "---:|" * (len(head) - 1))
    total = [0, 0]
    files = {}
    for name in names:
        img = corpus[name]
        with triangle_alone():
            before = codec.encode(img)
        after = files[name] = codec.encode(img)
        free, ties, flips = ties_and_flips(after)
        ufree, uties, uflips = ties_and_flips(codec.encode(img, mesher="uniform"))
        total[0] += len(before)
        total[1] += len(after)
        row = [name, f"{free:,}", f"{100 * ties / max(free, 1):.2f}", f"{flips:,}", f"{ufree:,}",
               f"{100 * uties / max(ufree, 1):.2f}", f"{uflips:,}", f"{len(before):,}", f"{len(after):,}",
               f"{100 * (len(after) - len(before)) / len(before):+.3f}"]
        print("| " + " | ".join(row) + " |", flush=True)
    print(f"| all | | | | | | | {total[0]:,} | {total[1]:,} | {100 * (total[1] - total[0]) / total[0]:+.3f} |")

    print()
    print("| image | triangles | decode ms | pass ms | pass / decode % |")
    print("|---|---:|---:|---:|---:|")
    for name in args.timed:
        data = files.get(name) or codec.encode(corpus[name])
        work = []
        for v, walls, tris in bands(data):
            with triangle_alone():
                work.append((v, triangulate_module.by_triangle(v, walls), walls))
        times = interleaved({
            "decode": lambda: codec.decode(data),
            "pass": lambda: [canonical.canonicalise(v, raw, walls) for v, raw, walls in work],
        }, args.repeat)
        share = statistics.median(p / d for p, d in zip(times["pass"], times["decode"]))
        triangles = sum(len(t) for _, t, _ in work)
        print(f"| {name} | {triangles:,} | {statistics.median(times['decode']):.2f} | "
              f"{statistics.median(times['pass']):.2f} | {100 * share:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

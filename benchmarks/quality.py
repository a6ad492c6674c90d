"""Quality benchmark: .atm's adaptive mesher against the uniform grid and pydelatin.

For every public corpus image (tests/corpus.py) at 1 % and 2.8 % vertex density, and the
two reference images of "Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular Meshes"
(section 3.3.2.3) at its vertex counts, prints the vertex count, RMS
and time of

* atm      codec.encode (default adaptive mesher), decoded with codec.decode;
* uniform  codec.encode(mesher="uniform"), decoded the same way;
* delatin  pydelatin (greedy insertion) with max_error bisected to the same vertex
           count; its vertices (y from the bottom: row = height - 1 - y) are
           Delaunay-triangulated with codec.triangulate, take their pixel values and
           are decoded by codec's CPU decoder.

and the ratios the acceptance criteria use (RMS against uniform and pydelatin, time
against pydelatin; the time ratio counts for 512 x 512 images). The three run in
turn, --repeat rounds (5), in the same process: times are medians, and the time
ratio is the median of the rounds' atm / pydelatin ratios. Writes the adaptive mesh
drawn over each image to benchmarks/out/<name>_<points>.png.

The disparity map motorcycle_disp.npz (skimage's data directory) is made 8-bit as the
tests do: infinite values (holes) become 0 and the finite range is scaled linearly to
0..255 and rounded.

    python benchmarks/quality.py [--quick | --repeat N] [--no-png] [--reference DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import codec  # noqa: E402
from codec.decoder_cpu import render  # noqa: E402
from codec.mesh import Mesh  # noqa: E402
from tests.synthetic import range_scene  # noqa: E402
from codec.triangulate import triangulate  # noqa: E402

REFERENCE = ROOT.parent / "shared" / "reference-images"
DENSITIES = (0.01, 0.028)


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def timed(fns: dict, repeat: int) -> tuple[dict, dict]:
    """(each function's result, its wall times over `repeat` runs, as an array). The
    functions run in turn, round after round, so that a slow spell on a shared machine
    weighs on all of them alike rather than on whichever ran during it."""
    out, times = {}, {key: [] for key in fns}
    for _ in range(repeat):
        for key, fn in fns.items():
            t = time.perf_counter()
            out[key] = fn()
            times[key].append(time.perf_counter() - t)
    return out, {key: np.array(v) for key, v in times.items()}


def codec_result(img: np.ndarray, data: bytes):
    return codec.info(data)["vertices"], rms(codec.decode(data), img)


def delatin_vertices(img: np.ndarray, max_error: float) -> np.ndarray:
    from pydelatin import Delatin

    h = img.shape[0]
    v = np.asarray(Delatin(img.astype(np.float32), max_error=max_error).vertices)
    xy = np.stack([v[:, 0], h - 1 - v[:, 1]], axis=1).astype(np.int64)
    return np.unique(xy, axis=0)


def delatin_error(img: np.ndarray, n: int) -> float:
    """pydelatin's max_error, bisected until its vertex count is within 1 % of n."""
    lo, hi = 0.0, float(img.max()) + 1
    err = hi / 2
    for _ in range(40):
        err = (lo + hi) / 2
        count = len(delatin_vertices(img, err))
        if abs(count - n) <= 0.01 * n:
            break
        if count > n:
            lo = err
        else:
            hi = err
    return err


def delatin_result(img: np.ndarray, verts: np.ndarray):
    h, w = img.shape
    mesh = Mesh(verts, img[verts[:, 1], verts[:, 0]], triangulate(verts), w, h)
    return len(verts), rms(render(mesh), img)


def corpus() -> dict[str, np.ndarray]:
    from tests.corpus import load_corpus

    images = load_corpus()
    for seed in (0, 1, 2):
        images[f"range_scene{seed}"] = range_scene(256, 256, seed=seed)
    return images


def reference(directory: Path) -> list[tuple[str, np.ndarray, int]]:
    import cv2

    out = []
    for name, n in (("house_256.png", 1649), ("lena_gray_512.tif", 7492)):
        path = directory / name
        if path.exists():
            out.append((path.stem, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), n))
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="time one run instead of the median of REPEAT")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs of each (default 5)")
    parser.add_argument("--no-png", action="store_true", help="do not write mesh pictures")
    parser.add_argument("--reference", type=Path, default=REFERENCE, help="the paper's reference images (Lenna, House)")
    args = parser.parse_args(argv)
    repeat = 1 if args.quick else max(1, args.repeat)
    out_dir = ROOT / "benchmarks" / "out"
    out_dir.mkdir(parents=True, exist_ok=True)
    cases = [(name, img, round(d * img.size)) for name, img in corpus().items() for d in DENSITIES]
    cases += reference(args.reference)
    header = (
        f"{'image':18} {'size':>9} {'points':>6} | {'atm n':>6} {'rms':>6} {'s':>6} | "
        f"{'unif n':>6} {'rms':>6} {'s':>6} | {'delat n':>7} {'rms':>6} {'s':>6} | "
        f"{'/unif':>5} {'/delat':>6} {'t/delat':>7}"
    )
    # the first encode and decode import what the codec loads lazily: not timed
    warm = range_scene(64, 64, seed=0)
    codec.decode(codec.encode(warm, points=100))
    delatin_vertices(warm, 1.0)
    print(header)
    print("-" * len(header))
    worst = {"unif": 0.0, "delat": 0.0, "time": 0.0}
    for name, img, n in cases:
        err = delatin_error(img, n)
        out, seconds = timed(
            {
                "atm": lambda: codec.encode(img, points=n),
                "uniform": lambda: codec.encode(img, points=n, mesher="uniform"),
                "delatin": lambda: delatin_vertices(img, err),
            },
            repeat,
        )
        (an, ar), at = codec_result(img, out["atm"]), float(np.median(seconds["atm"]))
        (un, ur), ut = codec_result(img, out["uniform"]), float(np.median(seconds["uniform"]))
        (dn, dr), dt = delatin_result(img, out["delatin"]), float(np.median(seconds["delatin"]))
        ratio_u, ratio_d = ar / max(ur, 1e-9), ar / max(dr, 1e-9)
        # the ratio of each round's pair, then their median: a pair shares its moment
        ratio_t = float(np.median(seconds["atm"] / np.maximum(seconds["delatin"], 1e-9)))
        worst["unif"] = max(worst["unif"], ratio_u)
        worst["delat"] = max(worst["delat"], ratio_d)
        if img.shape == (512, 512):
            worst["time"] = max(worst["time"], ratio_t)
        h, w = img.shape
        print(
            f"{name:18} {w:>4}x{h:<4} {n:>6} | {an:>6} {ar:>6.2f} {at:>6.3f} | "
            f"{un:>6} {ur:>6.2f} {ut:>6.3f} | {dn:>7} {dr:>6.2f} {dt:>6.3f} | "
            f"{ratio_u:>5.2f} {ratio_d:>6.2f} {ratio_t:>7.2f}",
            flush=True,
        )
        if not args.no_png:
            from codec.export import overlay_png, png_bytes

            m = codec.build_mesh(img, points=n)
            scale = 2 if max(h, w) <= 512 else 1
            (out_dir / f"{name}_{n}.png").write_bytes(png_bytes(overlay_png(m, img, scale=scale)))
    print(
        f"worst: RMS/uniform {worst['unif']:.2f} (target <= 0.75), RMS/pydelatin "
        f"{worst['delat']:.2f} (<= 1.1), time/pydelatin at 512x512 {worst['time']:.2f} (<= 3)"
    )


if __name__ == "__main__":
    main()

"""Rate-distortion: RMS and PSNR against bytes for .atm and the formats a user would
otherwise pick (JPEG, WebP, JPEG 2000 through OpenCV), on the public corpus.

    python benchmarks/rate.py                  # table on stdout, plot in benchmarks/out/
    python benchmarks/rate.py --images camera motorcycle_disp --bpp 0.1 0.2
    python benchmarks/rate.py --effort 3       # the slower, more thorough mesher

Every codec is brought to the same byte budget by bisection on its own knob (quality
for the peers, the vertex count for .atm), taking the largest setting that fits. Two
extra rows per image compare at the byte sizes of JPEG quality 5 and 10.
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
from tests.synthetic import range_scene  # noqa: E402

OUT = ROOT / "benchmarks" / "out"
RANGE_IMAGES = {"motorcycle_disp", "scene0", "scene1", "scene2"}


def corpus() -> dict[str, np.ndarray]:
    from tests.corpus import load_corpus

    images = load_corpus()
    for seed in range(3):
        images[f"scene{seed}"] = range_scene(512, 384, seed=seed)
    return images


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def psnr(e: float) -> float:
    return float("inf") if e == 0 else 20 * np.log10(255.0 / e)


PEERS = {
    "jpeg": (".jpg", "IMWRITE_JPEG_QUALITY", 1, 100),
    "webp": (".webp", "IMWRITE_WEBP_QUALITY", 1, 100),
    "jpeg2000": (".jp2", "IMWRITE_JPEG2000_COMPRESSION_X1000", 1, 1000),
}


def peer(image: np.ndarray, name: str, q: int) -> tuple[int, float]:
    import cv2

    ext, flag, _, _ = PEERS[name]
    ok, buf = cv2.imencode(ext, image, [getattr(cv2, flag), int(q)])
    mode = cv2.IMREAD_GRAYSCALE if image.ndim == 2 else cv2.IMREAD_COLOR
    return len(buf), rms(cv2.imdecode(buf, mode), image)


def largest_fitting(fn, lo: int, hi: int, budget: int) -> tuple[int, float] | None:
    """(bytes, rms) of fn(k) for the largest k in [lo, hi] whose size fits the budget
    (sizes grow with k); None if even fn(lo) is too big."""
    size, err = fn(lo)
    if size > budget:
        return None
    best = (size, err)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        size, err = fn(mid)
        if size <= budget:
            lo, best = mid, (size, err)
        else:
            hi = mid
    size, err = fn(hi)
    return (size, err) if size <= budget else best


#: encoder options for every .atm encode (rate.py --effort sets "effort")
OPTIONS: dict = {}


def atm(image: np.ndarray, points: int) -> tuple[int, float]:
    data = codec.encode(image, points=points, **OPTIONS)
    return len(data), rms(codec.decode(data), image)


def atm_at(image: np.ndarray, budget: int) -> tuple[int, float] | None:
    """.atm at the largest vertex count that fits: doubling to a bracket, then bisection."""
    pixels = image.shape[0] * image.shape[1]
    if atm(image, 4)[0] > budget:
        return None
    lo = 4
    while lo * 2 <= pixels and atm(image, lo * 2)[0] <= budget:
        lo *= 2
    return largest_fitting(lambda n: atm(image, n), lo, min(pixels, lo * 2), budget)


def holes_table(bpps: list[float]) -> None:
    """The disparity map with its holes kept as nodata: RMS over valid pixels against
    bytes; the peers get the image with holes filled from the nearest valid pixel, their
    best case (they cannot store a hole)."""
    from codec.holes import fill
    from tests.corpus import disparity, disparity_holes

    image, holes = disparity(), disparity_holes()
    filled = fill(image, holes)
    valid = ~holes
    h, w = image.shape

    def atm_masked(n: int) -> tuple[int, float]:
        data = codec.encode(image, points=n, mask=holes, nodata=0, **OPTIONS)
        out = codec.decode(data)
        return len(data), rms(out[valid], image[valid])

    def peer_filled(name: str, q: int) -> tuple[int, float]:
        import cv2

        ext, flag, _, _ = PEERS[name]
        ok, buf = cv2.imencode(ext, filled, [getattr(cv2, flag), int(q)])
        return len(buf), rms(cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)[valid], image[valid])

    print(f"\nmotorcycle_disp with {holes.mean():.1%} holes kept as nodata (RMS over valid pixels)\n")
    print("| budget | .atm (holes exact) | WebP (filled) | JPEG 2000 (filled) |")
    print("|---|---:|---:|---:|")
    for bpp in bpps:
        budget = int(bpp * h * w / 8)
        lo = 4
        while atm_masked(lo * 2)[0] <= budget and lo * 2 <= h * w:
            lo *= 2
        cells = [largest_fitting(atm_masked, lo, lo * 2, budget)]
        for name in ("webp", "jpeg2000"):
            _, _, qlo, qhi = PEERS[name]
            cells.append(largest_fitting(lambda q: peer_filled(name, q), qlo, qhi, budget))
        print(f"| {bpp:g} bpp | " + " | ".join(fmt(c) for c in cells) + " |", flush=True)


def elevation_table() -> None:
    """A float elevation model (metres) under max_error bounds."""
    z = range_scene(512, 512, seed=11, dtype=np.uint16).astype(np.float64) * 0.0015 + 412.0
    print(f"\nfloat elevation 512x512 ({z.min():.0f} .. {z.max():.0f} m): max_error in metres\n")
    print("| max_error | bytes | bits/pixel | measured max error | RMS |")
    print("|---:|---:|---:|---:|---:|")
    for bound in (0.01, 0.1, 0.5, 1.0, 2.0):
        data = codec.encode(z, max_error=bound)
        e = codec.decode(data).astype(np.float64) - z
        print(
            f"| {bound:g} m | {len(data):,} | {8 * len(data) / z.size:.3f} | "
            f"{np.abs(e).max():.4f} m | {np.sqrt(np.mean(e ** 2)):.4f} m |",
            flush=True,
        )


def at_budget(image: np.ndarray, budget: int) -> dict[str, tuple[int, float] | None]:
    row = {"atm": atm_at(image, budget)}
    for name, (_, _, lo, hi) in PEERS.items():
        row[name] = largest_fitting(lambda q: peer(image, name, q), lo, hi, budget)
    return row


def fmt(cell: tuple[int, float] | None) -> str:
    return "—" if cell is None else f"{cell[1]:.2f} ({cell[0]:,} B)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", nargs="+", help="corpus names (default: all)")
    parser.add_argument("--bpp", nargs="+", type=float, default=[0.05, 0.1, 0.2, 0.3, 0.5])
    parser.add_argument("--no-plot", action="store_true")
    parser.add_argument("--skip-holes", action="store_true", help="skip the nodata and float tables")
    parser.add_argument("--effort", type=int, choices=(1, 2, 3), help="the adaptive mesher's effort (default: the codec's)")
    args = parser.parse_args()
    if args.effort is not None:
        OPTIONS["effort"] = args.effort
    images = corpus()
    names = args.images or list(images)
    curves: dict[str, dict[str, list]] = {}
    print("RMS (bytes) at equal size; lower RMS is better\n")
    print("| image | budget | .atm | JPEG | WebP | JPEG 2000 | .atm / JPEG |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name in names:
        image = images[name]
        h, w = image.shape[:2]
        budgets = [(f"{b:g} bpp", int(b * h * w / 8)) for b in args.bpp]
        budgets += [(f"JPEG q{q}", peer(image, "jpeg", q)[0]) for q in (5, 10)]
        curves[name] = {k: [] for k in ("atm", "jpeg", "webp", "jpeg2000")}
        start = time.perf_counter()
        for label, budget in budgets:
            row = at_budget(image, budget)
            ratio = (
                f"{row['atm'][1] / row['jpeg'][1]:.2f}"
                if row["atm"] and row["jpeg"] and row["jpeg"][1] > 0
                else "—"
            )
            print(
                f"| {name} | {label} | {fmt(row['atm'])} | {fmt(row['jpeg'])} | "
                f"{fmt(row['webp'])} | {fmt(row['jpeg2000'])} | {ratio} |",
                flush=True,
            )
            if label.endswith("bpp"):
                for k, cell in row.items():
                    if cell is not None:
                        curves[name][k].append((8 * cell[0] / (h * w), psnr(cell[1])))
        print(f"<!-- {name}: {time.perf_counter() - start:.0f} s -->", file=sys.stderr)
    if not args.skip_holes:
        holes_table(args.bpp)
        elevation_table()
    if not args.no_plot:
        plot(curves)


def plot(curves: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    OUT.mkdir(parents=True, exist_ok=True)
    n = len(curves)
    cols = min(3, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.6 * rows), squeeze=False)
    for ax, (name, series) in zip(axes.ravel(), curves.items()):
        for k, pts in series.items():
            if pts:
                x, y = zip(*pts)
                ax.plot(x, y, marker="o", label=k)
        ax.set_title(name)
        ax.set_xlabel("bits per pixel")
        ax.set_ylabel("PSNR (dB)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.tight_layout()
    path = OUT / "rate.png"
    fig.savefig(path, dpi=90)
    print(f"\nplot: {path}")


if __name__ == "__main__":
    main()

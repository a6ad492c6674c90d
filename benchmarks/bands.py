"""Decode cost of many small bands: is decode time proportional to the file's bytes?

One image (skimage's camera, its first --width columns tiled down to --bands + 1 rows)
is encoded with one new row per band (--bands bands), ten rows per band, 64 rows per
band and as one band. Each file is decoded in interleaved rounds (every round decodes
each file once, so that load on a shared machine hits all alike); the table gives the
median time, the time per band and per stored byte, and each file's median per-round
ratio to the 64-row file.

    python benchmarks/bands.py                     # 20,000 one-row bands (encoding: minutes)
    python benchmarks/bands.py --bands 2000 --repeat 5 --profile

Encoded files are kept in --cache (default: the system's temporary folder), keyed by
their parameters, because encoding 20,000 bands takes minutes. --profile prints where a
decode of the one-row file spends its time (cProfile, by own time).
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import pstats
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import codec  # noqa: E402


def image(rows: int, width: int) -> np.ndarray:
    """skimage's camera, its first `width` columns tiled down to `rows` rows."""
    from skimage import data

    camera = data.camera()[:, :width]
    return np.ascontiguousarray(np.tile(camera, (-(-rows // len(camera)), 1))[:rows])


def encoded(img: np.ndarray, band_height: int | None, cache: Path) -> bytes:
    """codec.encode(img, band_height=...), from the cache when it has it."""
    key = hashlib.sha256(img.tobytes() + repr((img.shape, band_height)).encode()).hexdigest()[:16]
    path = cache / f"atm-bands-{key}.atm"
    if path.exists():
        return path.read_bytes()
    data = codec.encode(img, band_height=band_height)
    path.write_bytes(data)
    return data


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bands", type=int, default=20000, help="one-row bands of the largest file")
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds")
    ap.add_argument("--backend", default="cpu", choices=("cpu", "gl"))
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()))
    ap.add_argument("--profile", action="store_true", help="profile one decode of the one-row file")
    args = ap.parse_args()

    img = image(args.bands + 1, args.width)
    files = {}
    for band_height in (1, 10, 64, None):
        t0 = time.perf_counter()
        files[band_height] = encoded(img, band_height, args.cache)
        print(f"encoded band_height={band_height}: {len(files[band_height]):,} B "
              f"in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    for data in files.values():  # warm-up (the files are lossy codings of one image)
        assert codec.decode(data, backend=args.backend).shape == img.shape
    times: dict = {k: [] for k in files}
    for _ in range(args.repeat):
        for k, data in files.items():
            t0 = time.perf_counter()
            codec.decode(data, backend=args.backend)
            times[k].append(time.perf_counter() - t0)
    print(f"{img.shape[1]}x{img.shape[0]} image, backend {args.backend}, median of {args.repeat} interleaved rounds")
    print("| rows per band | bands | bytes | decode ms | us per band | ns per byte | ratio to 64 rows |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for k, data in files.items():
        bands = codec.info(data)["bands"]
        med = statistics.median(times[k])
        ratio = statistics.median(a / b for a, b in zip(times[k], times[64]))
        print(f"| {k or 'all'} | {bands:,} | {len(data):,} | {1e3 * med:.1f} | {1e6 * med / bands:.1f} | "
              f"{1e9 * med / len(data):.0f} | {ratio:.2f} |")
    if args.profile:
        data = files[1]
        prof = cProfile.Profile()
        prof.runcall(codec.decode, data, backend=args.backend)
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()

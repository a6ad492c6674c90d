"""Peak memory of streaming: `atm encode big.pgm - | atm decode - out.pgm`.

    python benchmarks/stream.py                    # 8192 x 8192 and a 4x taller image
    python benchmarks/stream.py --width 2048 --heights 2048 8192

Each process's peak resident memory comes from GNU time (`/usr/bin/time -v`, Debian
package `time`). For scale, the same figure for OpenCV reading the whole PGM is shown.
The test images are range scenes written band by band, so making them needs little
memory either; they go to a temporary folder (or --workdir) and are deleted afterwards.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

BLOCK = 512


def scene_rows(width: int, y0: int, y1: int, seed: int = 0) -> np.ndarray:
    """Rows y0..y1-1 of an endless range scene: tilted planes, disc-shaped objects on a
    fixed lattice with depth steps at their rims, and a smooth swell."""
    rng = np.random.default_rng(seed)
    cell = 700
    jitter = rng.uniform(0.2, 0.8, size=(64, 64, 4))
    yy, xx = np.mgrid[y0:y1, 0:width].astype(np.float64)
    depth = 60 + 0.004 * xx + 0.003 * (yy % 5000) + 10 * np.sin(xx / 900.0) * np.cos(yy / 1300.0)
    cy, cx = (yy // cell).astype(int) % 64, (xx // cell).astype(int) % 64
    j = jitter[cy, cx]
    ox = (xx // cell) * cell + j[..., 0] * cell
    oy = (yy // cell) * cell + j[..., 1] * cell
    r = (0.15 + 0.2 * j[..., 2]) * cell
    inside = (xx - ox) ** 2 + (yy - oy) ** 2 < r**2
    surface = 110 + 120 * j[..., 3] + 0.02 * (xx - ox) - 0.015 * (yy - oy)
    depth = np.where(inside, surface, depth)
    return np.clip(np.round(depth), 0, 255).astype(np.uint8)


def write_pgm(path: Path, width: int, height: int) -> None:
    with open(path, "wb") as f:
        f.write(f"P5\n{width} {height}\n255\n".encode())
        for y in range(0, height, BLOCK):
            f.write(scene_rows(width, y, min(height, y + BLOCK)).tobytes())


def peak_kb(report: str) -> int:
    return int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", report).group(1))


def rms_of(original: Path, decoded: Path, width: int, height: int) -> float:
    """RMS between two PGMs, read a block of rows at a time."""
    total = 0.0
    with open(original, "rb") as a, open(decoded, "rb") as b:
        for f in (a, b):
            for _ in range(3):
                f.readline()
        for y in range(0, height, BLOCK):
            n = min(BLOCK, height - y) * width
            x = np.frombuffer(a.read(n), np.uint8).astype(np.float64)
            z = np.frombuffer(b.read(n), np.uint8).astype(np.float64)
            total += float(((x - z) ** 2).sum())
    return (total / (width * height)) ** 0.5


def measure(work: Path, width: int, height: int) -> dict:
    src, out = work / f"in_{height}.pgm", work / f"out_{height}.pgm"
    write_pgm(src, width, height)
    atm = [sys.executable, "-m", "codec"]
    t = ["/usr/bin/time", "-v", "-o"]
    enc_rep, dec_rep, cv_rep = work / "enc.txt", work / "dec.txt", work / "cv.txt"
    start = time.perf_counter()
    enc = subprocess.Popen(t + [str(enc_rep)] + atm + ["encode", str(src), "-"], stdout=subprocess.PIPE)
    dec = subprocess.Popen(t + [str(dec_rep)] + atm + ["decode", "-", str(out)], stdin=enc.stdout)
    enc.stdout.close()
    if dec.wait() or enc.wait():
        raise SystemExit("the pipeline failed")
    seconds = time.perf_counter() - start
    subprocess.run(
        t + [str(cv_rep), sys.executable, "-c", f"import cv2; assert cv2.imread({str(src)!r}, 0) is not None"],
        check=True,
    )
    row = {
        "size": f"{width}x{height}",
        "encode_mb": peak_kb(enc_rep.read_text()) / 1024,
        "decode_mb": peak_kb(dec_rep.read_text()) / 1024,
        "cv2_imread_mb": peak_kb(cv_rep.read_text()) / 1024,
        "seconds": seconds,
        "rms": rms_of(src, out, width, height),
    }
    src.unlink()
    out.unlink()
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=8192)
    parser.add_argument("--heights", type=int, nargs="+", default=[8192, 32768])
    parser.add_argument("--workdir", help="folder for the temporary images (default: a temporary folder)")
    args = parser.parse_args()
    if not Path("/usr/bin/time").exists():
        raise SystemExit("needs GNU time at /usr/bin/time (Debian package 'time')")
    work = Path(tempfile.mkdtemp(dir=args.workdir))
    try:
        print("| image | encode peak MB | decode peak MB | cv2.imread peak MB | pipeline s | RMS |")
        print("|---|---:|---:|---:|---:|---:|")
        rows = []
        for h in args.heights:
            r = measure(work, args.width, h)
            rows.append(r)
            print(
                f"| {r['size']} | {r['encode_mb']:.0f} | {r['decode_mb']:.0f} | "
                f"{r['cv2_imread_mb']:.0f} | {r['seconds']:.1f} | {r['rms']:.2f} |",
                flush=True,
            )
        if len(rows) > 1:
            a, b = rows[0], rows[-1]
            print(
                f"\npeak growth from {a['size']} to {b['size']}: encode "
                f"{b['encode_mb'] / a['encode_mb']:.3f}x, decode {b['decode_mb'] / a['decode_mb']:.3f}x"
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

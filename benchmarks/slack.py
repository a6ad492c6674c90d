"""The mesh's slack under max_error on float data (codec.slack), measured: bytes and
vertices of the mesh alone (residual=False) with slack 0 and slack 1, and which the
rule picks, at bounds given as multiples of the rule's threshold.

    python benchmarks/slack.py                      # synthetic DEM 512², range data, corpus
    python benchmarks/slack.py --data srtm kinect --multiples 0.5 1 2 4

Data (float32; holes NaN): `dem512`/`dem1024` (benchmarks/speed.py's synthetic DEM),
`srtm` (../shared/range-data/srtm_dem.tif), `kinect`, `tum` (their depth maps, 0 = hole),
or a corpus image name (tests/corpus.py) as float32.
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
from tests.corpus import range_data  # noqa: E402
from codec import quantise, slack  # noqa: E402

RANGE_DATA = range_data()


def load(name: str) -> np.ndarray:
    """One of the data sets named in the module's docstring, as float32."""
    import cv2

    if name.startswith("dem"):
        from benchmarks.speed import dem

        return dem(int(name[3:]))
    if name == "srtm":
        import tifffile

        return tifffile.imread(RANGE_DATA / "srtm_dem.tif").astype(np.float32)
    if name in ("kinect", "tum"):
        path = RANGE_DATA / ("kinect_depth.pgm" if name == "kinect" else "tum_depth.png")
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32)
        depth[depth == 0] = np.nan
        return depth
    from tests.corpus import load_corpus

    return load_corpus()[name].astype(np.float32)


def threshold(rough: tuple[float, float] | None) -> float:
    """The smallest max_error at which the rule gives the mesh a level of slack."""
    if rough is None:
        return float("inf")
    median, upper = rough
    return max(slack.SLACK_MEDIAN * median, slack.SLACK_UPPER * upper)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", nargs="*", default=["dem512", "srtm", "kinect", "tum", "motorcycle_disp"])
    parser.add_argument("--multiples", type=float, nargs="*", default=[0.5, 1.5, 4.0],
                        help="bounds as multiples of the rule's threshold")
    args = parser.parse_args(argv)
    print("| data | Laplacian median, q75 | max error | slack 0 bytes | vertices | slack 1 bytes | vertices "
          "| slack 1 / 0 | rule picks | smaller | encode s (rule) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---|---:|")
    for name in args.data:
        img = load(name)
        valid = np.isfinite(img)
        rough = slack.roughness(img, ~valid)
        lo, hi = float(img[valid].min()), float(img[valid].max())
        for m in args.multiples:
            e = float(f"{max(m * threshold(rough), 1e-3):.3g}")
            sizes = []
            for s in (0, 1):
                step = quantise.step_for_error(lo, hi, e, s)
                data = codec.encode(img, max_error=e, residual=False, precision=step)
                sizes.append((len(data), codec.info(data)["vertices"]))
            t = time.perf_counter()
            chosen = codec.encode(img, max_error=e, residual=False)
            t = time.perf_counter() - t
            err = float(np.abs(codec.decode(chosen)[valid].astype(np.float64) - img[valid]).max())
            assert err <= e, (name, e, err)
            pick = slack.mesh_slack(e, rough)
            (b0, v0), (b1, v1) = sizes
            # the rule's file is one of the two (the same step), unless a step did not fit
            smaller = "yes" if sizes[pick][0] <= sizes[1 - pick][0] else "no"
            print(f"| {name} | {rough[0]:.3g}, {rough[1]:.3g} | {e:g} | {b0:,} | {v0:,} | {b1:,} | {v1:,} "
                  f"| {b1 / b0:.3f} | {pick} | {smaller} | {t:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

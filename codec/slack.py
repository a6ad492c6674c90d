"""How many levels of `max_error` the mesh gets on float data (the mesh-only path).

Under `max_error=E` alone, float data is quantised with a step of E / (slack + 1/2)
(quantise.step_for_error): slack 0 leaves the mesh no error at all (every level
exact, a step of about 2E), slack 1 a level of its own. A level of slack lets a
triangle bend across a smooth, curved surface instead of needing a vertex wherever
the surface leaves a level; it costs finer levels, so more bits per vertex value and
residual wobble the mesh must follow. Which wins depends on how E compares with the
surface's curvature between neighbouring pixels, which the first band shows.
"""

from __future__ import annotations

import numpy as np

#: The mesh gets a level of slack when E is at least both these multiples of the
#: median and of the upper quartile of the data's |4-neighbour Laplacian| (`roughness`).
#: Measured, mesh only, bytes with slack 1 against slack 0 (table in the commit
#: message; SRTM, Kinect and TUM depth, synthetic DEMs, corpus images as float32): the
#: crossover lies at 0.6-0.7 x the median on the DEMs and on TUM depth, but at 1.2 x on
#: Kinect depth and 2.2 x on a photo, whose Laplacians are heavy-tailed (sensor steps,
#: texture); the upper quartile catches those (crossover 0.3-0.55 x it). Slack 2 was
#: smaller only on the synthetic DEM (-11 to -20 % against slack 1 at E > 2 x the
#: median); on the SRTM, Kinect and TUM depth it was larger by up to 4 %, or tied.
SLACK_MEDIAN = 0.75
SLACK_UPPER = 0.35
#: Rows of the first band measured (evenly spaced): the median settles long before.
SAMPLE_ROWS = 256


def roughness(rows: np.ndarray, missing: np.ndarray | None = None) -> tuple[float, float] | None:
    """The median and upper quartile of |4 f(x, y) - f's four neighbours| over the
    pixels of `rows` whose five pixels all hold data (not `missing`, finite), in the
    data's units, measured around at most SAMPLE_ROWS evenly spaced rows; None if
    there are no such pixels."""
    f = np.asarray(rows, dtype=np.float64)
    if f.ndim != 2 or min(f.shape) < 3:
        return None
    if missing is not None:
        f = np.where(np.asarray(missing, bool), np.nan, f)
    centres = np.arange(1, len(f) - 1)
    if len(centres) > SAMPLE_ROWS:
        centres = np.linspace(1, len(f) - 2, SAMPLE_ROWS).round().astype(np.int64)
    up, mid, down = f[centres - 1], f[centres], f[centres + 1]
    with np.errstate(invalid="ignore", over="ignore"):
        lap = np.abs(4 * mid[:, 1:-1] - up[:, 1:-1] - down[:, 1:-1] - mid[:, :-2] - mid[:, 2:])
    lap = lap[np.isfinite(lap)]
    if not lap.size:
        return None
    median, upper = np.quantile(lap, [0.5, 0.75])
    return float(median), float(upper)


def mesh_slack(max_error: float, rough: tuple[float, float] | None) -> int:
    """Levels of max_error the mesh gets: 1 where E is at least SLACK_MEDIAN x the
    median and SLACK_UPPER x the upper quartile of `rough` (a surface smooth at the
    scale of E), else 0 (also when nothing could be measured)."""
    if rough is None:
        return 0
    median, upper = rough
    return int(max_error >= max(SLACK_MEDIAN * median, SLACK_UPPER * upper))

"""The public test corpus: scikit-image's bundled images (in the test extra) and its
motorcycle disparity map."""

from __future__ import annotations

from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parent.parent


def range_data() -> Path:
    """The project's shared range-data folder: shared/ beside the repository, or one
    level further up (a git worktree kept in a folder beside it). The first place when
    neither has it, so that a caller's missing file names where it was looked for."""
    places = [base / "shared" / "range-data" for base in (_ROOT.parent, _ROOT.parent.parent)]
    return next((p for p in places if p.is_dir()), places[0])


def disparity_raw() -> np.ndarray:
    """skimage's motorcycle disparity map as stored: float, infinite where unknown."""
    import skimage

    path = Path(skimage.__file__).parent / "data" / "motorcycle_disp.npz"
    return np.load(path)["arr_0"].astype(np.float64)


def disparity_holes() -> np.ndarray:
    """Where the disparity map has no measurement."""
    return ~np.isfinite(disparity_raw())


def disparity() -> np.ndarray:
    """The disparity map as uint8: holes become 0, the finite range is scaled linearly
    to 0..255."""
    disp = disparity_raw()
    disp[~np.isfinite(disp)] = 0
    return np.round(255 * disp / disp.max()).astype(np.uint8)


def load_corpus() -> dict[str, np.ndarray]:
    from skimage import color, data

    images = {
        "camera": data.camera(),
        "coins": data.coins(),
        "moon": data.moon(),
        "text": data.text(),
        "astronaut": np.round(255 * color.rgb2gray(data.astronaut())).astype(np.uint8),
        "motorcycle_disp": disparity(),
    }
    return images

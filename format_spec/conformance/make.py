"""Regenerate the conformance files: python format_spec/conformance/make.py

Each `.atm` here is written by the reference codec and its `.png` is the image a
conforming decoder must produce. Run this only when the format version changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import codec
from codec import encoder
from codec.files import write_image
from codec.mesh import Mesh
from codec.triangulate import triangulate

# the test scenes live with the tests, in the repository only
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests import synthetic  # noqa: E402

HERE = Path(__file__).resolve().parent


def walled_mesh() -> Mesh:
    """48x32 gray: a planar-steps scene with one vertical wall (x = 23 | x = 24) kept as
    two constraint polylines, over a 6-pixel grid."""
    w, h = 48, 32
    yy, xx = np.mgrid[0:h, 0:w]
    image = np.where(xx <= 23, 40 + xx + yy // 2, 200 - yy).astype(np.uint8)
    gx, gy = np.meshgrid(np.r_[0:23:6, 29:48:6, 47], np.r_[0:32:6, 31])
    grid = np.stack([gx.ravel(), gy.ravel()], 1)
    wall_y = np.r_[0:32:4, 31]
    left = np.stack([np.full_like(wall_y, 23), wall_y], 1)
    right = np.stack([np.full_like(wall_y, 24), wall_y], 1)
    vertices = np.unique(np.concatenate([grid, left, right]), axis=0)
    index = {tuple(p): i for i, p in enumerate(vertices.tolist())}
    walls = [np.array([index[tuple(p)] for p in side.tolist()]) for side in (left, right)]
    segments = np.concatenate([np.stack([c[:-1], c[1:]], 1) for c in walls])
    triangles = triangulate(vertices, segments)
    values = image[vertices[:, 1], vertices[:, 0]]
    return Mesh(vertices, values, triangles, w, h, walls)


def main() -> None:
    cases = {
        "gray8_steps": encoder.pack(walled_mesh()),
        "gray16_scene": codec.encode(
            synthetic.range_scene(40, 30, seed=3, dtype=np.uint16), points=120, mesher="uniform"
        ),
        "rgb8_grid": codec.encode(
            np.random.default_rng(5).integers(0, 256, (16, 24, 3), dtype=np.uint8),
            points=40,
            mesher="uniform",
        ),
        "bands_gray8": codec.encode(
            synthetic.range_scene(40, 30, seed=6), points=200, mesher="uniform", band_height=8
        ),
        # the adaptive mesher's walls, with free vertices clustered enough that their
        # positions go along the Hilbert curve
        "walls_hilbert": codec.encode(synthetic.range_scene(64, 48, seed=3), points=150),
        "line_1x9": codec.encode(
            np.array([[0, 30, 60, 90, 255, 200, 100, 50, 7]], np.uint8), points=4, mesher="uniform"
        ),
    }
    elevation = synthetic.range_scene(36, 24, seed=8).astype(np.float64) * 0.75 + 312.5
    cases["float_elevation"] = codec.encode(elevation, mesher="uniform", points=90, precision=0.01)
    depth = synthetic.range_scene(40, 30, seed=9).astype(np.float64) * 0.02 + 1.5
    depth[4:11, 6:19] = np.nan
    depth[20:, 33:] = np.nan
    cases["holes_float"] = codec.encode(
        depth, mesher="uniform", points=120, band_height=12, metadata={"units": "m"}
    )
    for name, data in cases.items():
        (HERE / f"{name}.atm").write_bytes(data)
        image = codec.decode(data)
        if image.dtype.kind == "f":
            np.save(HERE / f"{name}.npy", image)
        else:
            write_image(HERE / f"{name}.png", image)
        print(name, codec.info(data))


if __name__ == "__main__":
    main()

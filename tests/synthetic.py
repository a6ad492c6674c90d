"""Synthetic range scenes for tests, benchmarks and examples, generated from a seed.

A scene is a background surface with objects in front of it: each object is a
polygon or ellipse whose surface is a plane or a smooth bump, so the depth image has
sharp steps (the objects' outlines) between smooth or planar regions, like a range
image or a disparity map.
"""

from __future__ import annotations

import numpy as np


def _plane(rng, xx, yy, base, tilt):
    a, b = rng.uniform(-tilt, tilt, size=2)
    return base + a * (xx - xx.mean()) + b * (yy - yy.mean())


def range_scene(
    width: int = 256,
    height: int = 256,
    *,
    seed: int = 0,
    objects: int = 6,
    smooth: bool = True,
    dtype=np.uint8,
) -> np.ndarray:
    """A piecewise smooth depth image with depth steps at object outlines.

    smooth=False keeps every surface planar (piecewise-planar scene).
    """
    import cv2

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    top = float(np.iinfo(dtype).max)
    depth = _plane(rng, xx, yy, 0.25 * top, 0.1 * top / max(width, height))
    size = min(width, height)
    for _ in range(objects):
        mask = np.zeros((height, width), np.uint8)
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        r = rng.uniform(0.1, 0.3) * size
        if rng.random() < 0.5:
            angles = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 7)))
            radii = r * rng.uniform(0.6, 1.0, len(angles))
            pts = np.stack([cx + radii * np.cos(angles), cy + radii * np.sin(angles)], 1)
            cv2.fillPoly(mask, [np.round(pts).astype(np.int32)], 1)
        else:
            axes = (max(1, int(r)), max(1, int(r * rng.uniform(0.4, 1.0))))
            cv2.ellipse(mask, (int(cx), int(cy)), axes, rng.uniform(0, 180), 0, 360, 1, -1)
        base = rng.uniform(0.35, 0.9) * top
        surface = _plane(rng, xx, yy, base, 0.3 * top / max(width, height))
        if smooth and rng.random() < 0.5:
            bump = np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * (0.6 * r) ** 2))
            surface = surface + rng.uniform(-0.15, 0.15) * top * bump
        depth = np.where(mask.astype(bool), surface, depth)
    return np.clip(np.round(depth), 0, top).astype(dtype)


def planar_steps(width: int = 128, height: int = 96, *, seed: int = 0, dtype=np.uint8) -> np.ndarray:
    """Planar regions separated by straight depth steps: a few half-planes stacked.

    Each step is at least 40 gray levels high, and every region is an exact plane, so a
    mesh with walls on the steps can reproduce the image exactly away from them.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    top = float(np.iinfo(dtype).max)
    unit = top / 255.0
    depth = 40 * unit + 0.1 * unit * xx + 0.05 * unit * yy
    level = 40 * unit
    for _ in range(int(rng.integers(2, 4))):
        angle = rng.uniform(0, np.pi)
        nx, ny = np.cos(angle), np.sin(angle)
        offset = rng.uniform(0.3, 0.7) * (abs(nx) * width + abs(ny) * height) + min(0, nx * width) + min(0, ny * height)
        side = nx * xx + ny * yy > offset
        level += 45 * unit
        gx, gy = rng.uniform(-0.15, 0.15, 2) * unit
        depth = np.where(side, level + gx * (xx - width / 2) + gy * (yy - height / 2), depth)
    return np.clip(np.round(depth), 0, top).astype(dtype)

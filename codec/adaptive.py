"""The discontinuity-preserving adaptive mesher (the seed's §3.3.2), the default.

Stages, each in its own module: Canny edges (codec.edges), edge polylines by the
seed's segment rule (codec.polylines), their unfolding into parallel polylines that
become the walls (codec.unfold), curvature-driven region sampling over tiles
(codec.sampling), then a constrained Delaunay triangulation with the walls as
constraint segments and the image corners included (codec.triangulate).

Beyond the seed: a vertex budget (`points`) shared between the stages, error-driven
refinement that spends what the edges and regions left over where the mesh is worst
(the seed's coarse-to-fine refinement of §3.3.1, in batches), and least-squares
vertex values (codec.values).
"""

from __future__ import annotations

import math

import numpy as np

from . import edges as edge_stage
from . import polylines as polyline_stage
from . import sampling
from . import values as vertex_values
from .errors import OptionError
from .image import structure
from .mesh import Mesh
from .raster import RowPrefix, element_sse, rasterize
from .triangulate import split_at_vertices, triangulate
from .unfold import Walls, unfold

#: Default shares of the vertex budget: at most EDGE_SHARE on walls, REGION_SHARE on
#: curvature sampling; refinement takes the rest.
EDGE_SHARE = 0.3
REGION_SHARE = 0.3
#: Side of a tile in pixels when tiles are chosen automatically.
TILE = 80
#: Refinement rounds: each inserts about an equal part of what is left.
ROUNDS = 4


def _check_share(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not 0 <= value <= 1:
        raise OptionError(f"{name} must be a number from 0 to 1, not {value!r}")
    return float(value)


def _select_lines(lines: polyline_stage.Polylines, budget: int) -> polyline_stage.Polylines:
    """The polylines most worth their vertices (summed squared gradient per foot), as
    many as `budget` feet allow, most worthy first (so they win wall conflicts)."""
    feet = 2 * np.diff(lines.starts)
    worth = lines.strength / np.maximum(feet, 1)
    order = np.argsort(-worth, kind="stable")
    fits = np.cumsum(feet[order]) <= budget
    chosen = order[fits]
    keep = np.zeros(len(lines), dtype=bool)
    keep[chosen] = True
    picked = lines.select(keep)
    # select() keeps scan-line order; reorder by worth
    rank = np.argsort(np.argsort(-worth[keep], kind="stable"), kind="stable")
    return _reorder(picked, np.argsort(rank, kind="stable"))


def _reorder(lines: polyline_stage.Polylines, order: np.ndarray) -> polyline_stage.Polylines:
    sizes = np.diff(lines.starts)
    idx = np.concatenate([np.arange(lines.starts[k], lines.starts[k + 1]) for k in order]) if len(order) else np.zeros(0, np.int64)
    new_of_old = np.empty(len(order), dtype=np.int64)
    new_of_old[order] = np.arange(len(order))
    px_order = np.argsort(new_of_old[lines.pixel_line], kind="stable")
    return polyline_stage.Polylines(
        lines.points[idx],
        np.concatenate([[0], np.cumsum(sizes[order])]),
        lines.pixels[px_order],
        new_of_old[lines.pixel_line][px_order],
        lines.strength[order],
    )


def _excluded(lines: polyline_stage.Polylines, walls: Walls, shape: tuple[int, int]) -> np.ndarray:
    """Pixels on or next to the kept edges and walls: no region samples there."""
    import cv2

    mask = np.zeros(shape, dtype=np.uint8)
    mask[lines.pixels[:, 1], lines.pixels[:, 0]] = 1
    mask[walls.points[:, 1], walls.points[:, 0]] = 1
    return cv2.dilate(mask, np.ones((3, 3), np.uint8)).astype(bool)


def _corners(width: int, height: int) -> np.ndarray:
    c = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], dtype=np.int64)
    return c[np.unique(c[:, 1] * width + c[:, 0], return_index=True)[1]]


def _merge(width: int, *groups: np.ndarray) -> np.ndarray:
    """Concatenate point groups keeping the first of any points on the same pixel and
    the order of the groups (the first group's indices stay valid)."""
    pts = np.concatenate(groups)
    _, first = np.unique(pts[:, 1] * width + pts[:, 0], return_index=True)
    return pts[np.sort(first)]


def _chains(segments: np.ndarray) -> list[np.ndarray]:
    """Constraint polylines: the runs of segments that continue each other."""
    if len(segments) == 0:
        return []
    breaks = np.flatnonzero(segments[1:, 0] != segments[:-1, 1]) + 1
    return [np.append(segments[r, 0], segments[r[-1], 1]) for r in np.split(np.arange(len(segments)), breaks)]


def refine(
    gray: np.ndarray,
    vertices: np.ndarray,
    segments: np.ndarray,
    target: int,
    rounds: int = ROUNDS,
) -> np.ndarray:
    """Add vertices until there are `target`: in each round, the triangles with the
    largest squared error (against the mesh through the sampled pixel values) each get
    a vertex at their worst pixel. Pixels beside walls may get one: where a wall's
    straight segments cut a corner of the true edge, that is where the error is."""
    height, width = gray.shape
    prefix = RowPrefix(gray)
    for r in range(rounds):
        missing = target - len(vertices)
        if missing <= 0:
            break
        batch = math.ceil(missing / (rounds - r))
        tris = triangulate(vertices, segments)
        ras = rasterize(vertices, tris, width, height)
        z = gray[vertices[:, 1], vertices[:, 0]].astype(np.float64)
        sse = element_sse(ras, prefix, z)
        cand = np.argsort(-sse, kind="stable")[:batch]
        cand = cand[sse[cand] > 0]
        if len(cand) == 0:
            break
        elem, x, y = ras.pixels(np.sort(cand))  # grouped by element
        err = np.abs(gray[y, x] - ras.evaluate(ras.affine(z), elem, x, y))
        starts = np.flatnonzero(np.r_[True, elem[1:] != elem[:-1]])
        group = np.cumsum(np.r_[False, elem[1:] != elem[:-1]])
        # each element's worst pixel: the first reaching the element's maximum
        peak = np.maximum.reduceat(err, starts)
        at_peak = np.flatnonzero(err == peak[group])
        best = at_peak[np.r_[True, group[at_peak][1:] != group[at_peak][:-1]]]
        best = best[err[best] > 0.5]
        new = np.stack([x[best], y[best]], axis=1)
        if len(new) == 0:
            break
        vertices = _merge(width, vertices, new)
    return vertices


def build(
    image: np.ndarray,
    points: int,
    *,
    segment_length: int = 4,
    segment_error: float = 1.0,
    tiles: tuple[int, int] | None = None,
    per_tile: tuple[int, int] | None = None,
    canny: tuple[float, float] | None = None,
    edge_share: float = EDGE_SHARE,
    region_share: float = REGION_SHARE,
    values: str = "lsq",
) -> Mesh:
    """Mesh `image` with about `points` vertices, walls along its discontinuities.

    segment_length, segment_error: the seed's edge polyline rule (pixels).
    tiles=(H, V), per_tile=(R, Z): region sampling grid and samples per tile (by default
    chosen from `points`). canny=(low, high): edge thresholds in 8-bit gray levels
    (default: automatic). edge_share, region_share: parts of the budget for the walls
    (at most) and the region samples; the rest goes to error-driven refinement.
    values: "lsq" (least squares, default) or "sample" (the pixel values, as the seed).
    Explicit tiles and per_tile are honoured even when they give more than `points`.
    """
    if values not in vertex_values.METHODS:
        raise OptionError(f"unknown values method {values!r}; choose one of {', '.join(vertex_values.METHODS)}")
    edge_share = _check_share(edge_share, "edge_share")
    region_share = _check_share(region_share, "region_share")
    thresholds = edge_stage.check_thresholds(canny)
    tiles = None if tiles is None else sampling.check_pair(tiles, "tiles")
    per_tile = None if per_tile is None else sampling.check_pair(per_tile, "per_tile")
    height, width = image.shape[:2]
    gray = structure(image)
    peak = float(np.iinfo(image.dtype).max)
    corners = _corners(width, height)
    wall_pts = np.zeros((0, 2), np.int64)
    segments = np.zeros((0, 2), np.int64)
    excluded = np.zeros((height, width), dtype=bool)
    if width > 2 and height > 2:
        found, magnitude, _ = edge_stage.detect(gray, peak, thresholds)
        lines = polyline_stage.trace(
            found, magnitude, segment_length=segment_length, segment_error=segment_error
        )
        lines = _select_lines(lines, int(edge_share * points))
        walls = unfold(lines, gray * np.float32(255.0 / peak))
        wall_pts, segments = walls.points, walls.segments
        excluded = _excluded(lines, walls, (height, width))
    region = max(0, int(region_share * points))
    if tiles is None:
        tiles = (max(1, round(width / TILE)), max(1, round(height / TILE)))
    if per_tile is None:
        each = region / (tiles[0] * tiles[1])
        r = max(1, round(math.sqrt(each * width / max(1, tiles[0]) / max(1, height / tiles[1]))))
        per_tile = (r, max(1, round(each / r)))
    dens = sampling.density(sampling.curvature(gray), excluded)
    samples = sampling.sample(dens, tiles, per_tile) if region > 0 else np.zeros((0, 2), np.int64)
    vertices = _merge(width, wall_pts, corners, samples)
    vertices = refine(gray, vertices, segments, points)
    # vertices that landed on a wall split it, as the triangulation will
    segments = split_at_vertices(vertices, segments, width, height)
    triangles = triangulate(vertices, segments)
    vals = vertex_values.fit(image, vertices, triangles, values)
    return Mesh(vertices, vals, triangles, width, height, _chains(segments))

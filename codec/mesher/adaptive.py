"""The discontinuity-preserving adaptive mesher (the seed's §3.3.2), the default.

Stages, each in its own module: Canny edges (codec.mesher.edges), edge polylines by the
seed's segment rule (codec.mesher.polylines), their unfolding into parallel polylines that
become the walls (codec.mesher.unfold), curvature-driven region sampling over tiles
(codec.mesher.sampling), then a constrained Delaunay triangulation with the walls as
constraint segments and the image corners included (codec.triangulate).

Beyond the seed: a vertex budget (`points`) shared between the stages, error-driven
refinement that spends what the edges and regions left over where the mesh is worst
(the seed's coarse-to-fine refinement of §3.3.1, in batches), and least-squares
vertex values (codec.mesher.values).
"""

from __future__ import annotations

import itertools
import math
from types import MappingProxyType

import numpy as np

from . import edges as edge_stage
from . import polylines as polyline_stage
from . import sampling
from . import values as vertex_values
from ..errors import OptionError
from ..image import structure
from ..mesh import Mesh
from . import Meshed
from .elements import Statistics, concat, element_sse, line_raster, triangle_raster
from ..triangulate import split_at_vertices, triangulate
from .unfold import Walls, unfold

#: Default shares of the vertex budget: at most EDGE_SHARE on walls, REGION_SHARE on
#: curvature sampling (at the default effort); refinement takes the rest.
EDGE_SHARE = 0.3
REGION_SHARE = 0.3
#: Edge pixels traced per wall foot of the budget: a polyline's control points are a few
#: pixels apart and give two feet each, so this leaves the selection a wide choice.
TRACED = 8
#: Side of a tile in pixels when tiles are chosen automatically.
TILE = 80
#: Refinement rounds; each inserts part of what is left, the parts shrinking by DECAY
#: from round to round (later rounds see the effect of the earlier ones).
ROUNDS = 3
DECAY = 0.7
#: When the elements that would get a quarter of the refinement budget hold at least
#: this share of the squared error (steps in a piecewise-smooth image rather than
#: texture), insertions crowd each other and the budget goes in FOCUSED_ROUNDS rounds.
CONCENTRATED = 0.7
FOCUSED_ROUNDS = 6
#: effort -> (region share, rounds, focused rounds). Error-driven refinement places
#: vertices better than curvature sampling but costs a triangulation and a measure
#: per round: effort 3 leaves it 90 % of the budget in up to 8 rounds, for 2-5 %
#: lower RMS at equal bytes on the corpus and about 1.5x the encode time of effort 2
#: (the default); effort 1 is the quickest (benchmarks/quality.py, rate.py --effort).
EFFORTS = MappingProxyType({1: (0.5, 2, 3), 2: (REGION_SHARE, ROUNDS, FOCUSED_ROUNDS), 3: (0.1, ROUNDS, 8)})
#: Piecewise-smooth images (range images: surfaces and steps) keep less than
#: SMOOTH_OFF_EDGES of their curvature energy away from their edges. Curvature
#: sampling then has nothing to follow off the walls, and refinement places the
#: vertices better: such images get at most SMOOTH_REGION_SHARE of the budget for
#: region samples (the corpus' range images: 0.2-2 % off the edges, photos 11-40 %;
#: at 0.12 instead of 0.3, range scenes at 1 % density lose a quarter of their RMS;
#: 0.1 and 0.05 did about as well on average but worse on single scenes).
SMOOTH_OFF_EDGES = 0.05
SMOOTH_REGION_SHARE = 0.12


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


def _pixels(vertices: np.ndarray, triangles: np.ndarray, width: int, height: int):
    """(element, x, y) of every pixel, elements numbered as the triangles then the
    border lines (line_raster)."""
    e, x, y = triangle_raster(vertices, triangles, width, height).pixels()
    le, lx, ly = line_raster(vertices, width, height).pixels()
    return np.r_[e, le + len(triangles)], np.r_[x, lx], np.r_[y, ly]


def _off_edge_curvature(gray: np.ndarray, found: np.ndarray) -> float:
    """Share of the image's curvature energy (squared Laplacian) more than a pixel away
    from its edges."""
    import cv2

    energy = cv2.Laplacian(gray, cv2.CV_32F).astype(np.float64) ** 2
    total = float(energy.sum())
    if total == 0:
        return 0.0
    near = cv2.dilate(found.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return float(energy[~near].sum()) / total


def _corners(width: int, height: int) -> np.ndarray:
    c = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], dtype=np.int64)
    return c[np.unique(c[:, 1] * width + c[:, 0], return_index=True)[1]]


def _merge(width: int, *groups: np.ndarray) -> np.ndarray:
    """Concatenate point groups keeping the first of any points on the same pixel and
    the order of the groups (the first group's indices stay valid)."""
    pts = np.concatenate(groups)
    _, first = np.unique(pts[:, 1] * width + pts[:, 0], return_index=True)
    return pts[np.sort(first)]


def _run_breaks(segments: np.ndarray) -> np.ndarray:
    """Where a run of segments that continue each other ends and the next begins."""
    return np.flatnonzero(segments[1:, 0] != segments[:-1, 1]) + 1


def _chains(segments: np.ndarray) -> list[np.ndarray]:
    """Constraint polylines: the runs of segments that continue each other."""
    if len(segments) == 0:
        return []
    ends = np.r_[_run_breaks(segments), len(segments)]
    # each run's first vertices, then its last segment's end
    flat = np.insert(segments[:, 0], ends, segments[ends - 1, 1])
    return np.split(flat, ends[:-1] + np.arange(1, len(ends)))


def _keys(pixel: np.ndarray, triangles: np.ndarray, base: int) -> np.ndarray | None:
    """One integer per triangle from its corners' pixel numbers (`pixel`, below
    `base`), whichever corner it is listed from and however the vertices are numbered,
    or None when they would overflow int64."""
    if base**3 >= 2**62:
        return None
    a, b, c = pixel[triangles].T
    low, high = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    return (low * base + (a + b + c - low - high)) * base + high


class _Cache:
    """Statistics and squared errors (against the mesh through the sampled values) of
    the triangles of the last triangulation, by triangle, so that a triangle that
    survives a round is not measured again."""

    def __init__(self, layout: Statistics):
        self.layout = layout
        self.keys = np.zeros(0, np.int64)  # sorted
        self.stats = np.zeros((0, layout.width))
        self.sse = np.zeros(0)

    def measure(self, vertices: np.ndarray, triangles: np.ndarray, z: np.ndarray, width: int, height: int,
                last: bool = False):
        """(statistics and squared error of every triangle, indices of the new ones, a
        raster of the new ones). last: no round follows, so the squared errors are not
        needed (None) and the cache is not updated."""
        keys = _keys(vertices[:, 1] * width + vertices[:, 0], triangles, width * height)
        known = np.zeros(len(triangles), bool)
        pos = np.zeros(len(triangles), np.int64)
        if keys is not None:
            # looked up in key order: sorted queries make the binary searches cheap
            by_key = np.argsort(keys)
            sorted_keys = keys[by_key]
            if len(self.keys):
                found = np.minimum(np.searchsorted(self.keys, sorted_keys), len(self.keys) - 1)
                pos[by_key] = found
                known[by_key] = self.keys[found] == sorted_keys
        fresh = np.flatnonzero(~known)
        raster = triangle_raster(vertices, triangles[fresh], width, height)
        stats = np.empty((len(triangles), self.layout.width))
        sse = np.empty(len(triangles))
        measured = self.layout(raster)
        stats[fresh] = measured
        if known.any():
            stats[known] = np.take(self.stats, pos[known], axis=0)
        if last:
            return stats, None, fresh, raster
        sse[fresh] = element_sse(raster, measured, z)
        if known.any():
            sse[known] = self.sse[pos[known]]
        if keys is not None:
            # the cache for the next round: this triangulation's triangles (the
            # surviving entries and the new ones), in key order
            self.keys = sorted_keys
            self.stats = np.take(stats, by_key, axis=0)
            self.sse = sse[by_key]
        return stats, sse, fresh, raster


def _worst_pixels(gray, z, vertices, tris, fresh, fresh_raster, cand, width, height):
    """(triangle, x, y, |error|) of the worst pixel of each candidate triangle (sorted),
    from the raster of the new triangles where the candidate is one of them."""
    where = np.searchsorted(fresh, cand)
    is_new = (where < len(fresh)) & (fresh[np.minimum(where, len(fresh) - 1)] == cand) if len(fresh) else np.zeros(len(cand), bool)
    e1, x1, y1, err1 = fresh_raster.worst_pixels(gray, z, where[is_new])
    old = cand[~is_new]
    e2, x2, y2, err2 = triangle_raster(vertices, tris[old], width, height).worst_pixels(gray, z, np.arange(len(old)))
    return np.r_[fresh[e1], old[e2]], np.r_[x1, x2], np.r_[y1, y2], np.r_[err1, err2]


def _raster_order(vertices: np.ndarray, segments: np.ndarray, width: int, sort_walls: bool = False):
    """(vertices in raster order, the segments renumbered and cut at the vertices on
    them, the new position of every old vertex): the vertex order and wall steps a
    band's MESH chunk stores, which codec.meshcode triangulates again to check that a
    decoder rebuilds the same triangles. sort_walls: also put the runs of segments
    (the stored polylines) in the raster order of their first vertices, so that their
    stored starts are small forward gaps (about 30 % fewer bytes for them); only before
    a triangulation, which with cocircular vertices may depend on the segment order."""
    order = np.argsort(vertices[:, 1] * width + vertices[:, 0], kind="stable")
    renumber = np.empty(len(order), np.int64)
    renumber[order] = np.arange(len(order))
    vertices = vertices[order]
    segments = split_at_vertices(vertices, renumber[segments], width)
    if sort_walls and len(segments):
        firsts = np.r_[0, _run_breaks(segments)]
        first_vertex = np.repeat(segments[firsts, 0], np.diff(np.r_[firsts, len(segments)]))
        segments = segments[np.argsort(first_vertex, kind="stable")]
    return vertices, segments, renumber


def refine(
    gray: np.ndarray,
    vertices: np.ndarray,
    segments: np.ndarray,
    target: int,
    layout: Statistics,
    rounds: int = ROUNDS,
    focused_rounds: int = FOCUSED_ROUNDS,
):
    """Add vertices until there are `target`: in each round, the elements with the
    largest squared error (against the mesh through the sampled pixel values) each get
    a vertex at their worst pixel. Pixels beside walls may get one: where a wall's
    straight segments cut a corner of the true edge, that is where the error is.
    Rounds: `rounds`, or `focused_rounds` where the error is CONCENTRATED.

    Returns (vertices, segments, triangles, raster, stats, delaunay): the final
    vertices in raster order, the wall segments cut at the vertices on them, their
    triangulation, a raster of its elements (triangles then border lines; the
    triangles' spans are not kept), every element's statistics (`layout`, which must
    have `gray` as its structure plane) and whether the triangulation is the one a
    decoder rebuilds from the vertices and segments in that order (Meshed.delaunay).
    """
    height, width = gray.shape
    cache = _Cache(layout)
    ordered = False
    for r in itertools.count():
        if r == rounds or target <= len(vertices):
            # the last triangulation: made as the MESH chunk's check will make it
            vertices, segments, _ = _raster_order(vertices, segments, width, sort_walls=True)
            ordered = True
        z = gray[vertices[:, 1], vertices[:, 0]].astype(np.float64)
        tris = triangulate(vertices, segments)
        tri_stats, tri_sse, fresh, fresh_raster = cache.measure(vertices, tris, z, width, height, ordered)
        missing = target - len(vertices)
        if ordered:
            break
        lines = line_raster(vertices, width, height)
        sse = np.r_[tri_sse, element_sse(lines, layout(lines), z)]
        if r == 0:
            quarter = min(len(sse), math.ceil(missing / 4))
            if np.partition(sse, len(sse) - quarter)[len(sse) - quarter :].sum() >= CONCENTRATED * sse.sum():
                rounds = max(rounds, focused_rounds)
        weights = DECAY ** np.arange(rounds - r)
        batch = math.ceil(missing * weights[0] / weights.sum())
        if batch < len(sse):
            # the batch largest, ties to the lower index (as a stable sort would)
            cut = -np.partition(-sse, batch - 1)[batch - 1]
            above = np.flatnonzero(sse > cut)
            cand = np.r_[above, np.flatnonzero(sse == cut)[: batch - len(above)]]
        else:
            cand = np.arange(len(sse))
        cand = np.sort(cand[sse[cand] > 0])
        on_tri = cand[cand < len(tris)]
        t, x, y, err = _worst_pixels(gray, z, vertices, tris, fresh, fresh_raster, on_tri, width, height)
        _, lx, ly, lerr = lines.worst_pixels(gray, z, cand[cand >= len(tris)] - len(tris))
        order = np.argsort(t, kind="stable")
        x, y, err = np.r_[x[order], lx], np.r_[y[order], ly], np.r_[err[order], lerr]
        big = err > 0.5
        if not big.any():
            # nothing worth a vertex: keep this triangulation, in raster order
            vertices, segments, renumber = _raster_order(vertices, segments, width)
            tris = renumber[tris]
            break
        vertices = _merge(width, vertices, np.stack([x[big], y[big]], axis=1))
    lines = line_raster(vertices, width, height)
    elements = concat([triangle_raster(vertices, tris, width, height, spans=False), lines])
    return vertices, segments, tris, elements, np.concatenate([tri_stats, layout(lines)]), ordered


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
    region_share: float | None = None,
    values: str = "lsq",
    effort: int = 2,
) -> Meshed:
    """Mesh `image` with about `points` vertices, walls along its discontinuities.

    segment_length, segment_error: the seed's edge polyline rule (pixels).
    tiles=(H, V), per_tile=(R, Z): region sampling grid and samples per tile (by default
    chosen from `points`). canny=(low, high): edge thresholds in 8-bit gray levels
    (default: automatic). edge_share, region_share: parts of the budget for the walls
    (at most) and the region samples (default: by effort, less on piecewise-smooth
    images); the rest goes to error-driven refinement. effort: 1 (quickest), 2
    (default) or 3 (lowest error per byte, about 1.5x slower): how much of the budget
    refinement places, in how many rounds.
    values: "lsq" (least squares, default) or "sample" (the pixel values, as the seed).
    Explicit tiles and per_tile are honoured even when they give more than `points`.
    """
    if values not in vertex_values.METHODS:
        raise OptionError(f"unknown values method {values!r}; choose one of {', '.join(vertex_values.METHODS)}")
    if isinstance(effort, bool) or not isinstance(effort, (int, np.integer)) or effort not in EFFORTS:
        raise OptionError(f"effort must be 1, 2 or 3, not {effort!r}")
    default_share, rounds, focused_rounds = EFFORTS[effort]
    edge_share = _check_share(edge_share, "edge_share")
    if region_share is not None:
        region_share = _check_share(region_share, "region_share")
    smooth = False
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
        smooth = region_share is None and _off_edge_curvature(gray, found) < SMOOTH_OFF_EDGES
        budget = int(edge_share * points)
        lines = polyline_stage.trace(
            found, magnitude, segment_length=segment_length, segment_error=segment_error,
            max_pixels=TRACED * budget,
        )
        lines = _select_lines(lines, budget)
        walls = unfold(lines, gray * np.float32(255.0 / peak))
        wall_pts, segments = walls.points, walls.segments
        excluded = _excluded(lines, walls, (height, width))
    if region_share is None:
        region_share = min(default_share, SMOOTH_REGION_SHARE) if smooth else default_share
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
    fit = None if values != "lsq" else "structure" if image.ndim == 2 else image
    layout = Statistics(image if image.ndim == 2 else gray, fit)
    vertices, segments, triangles, elements, stats, delaunay = refine(
        gray, vertices, segments, points, layout, rounds, focused_rounds
    )
    if values == "lsq":
        vals = vertex_values.from_statistics(
            image, vertices, elements, stats, layout, lambda: _pixels(vertices, triangles, width, height)
        )
    else:
        vals = vertex_values.sample(image, vertices)
    mse = None
    if image.ndim == 2:
        # the statistics give the squared error of the planes through the values
        # exactly; decoders round each pixel to a level, which adds about 1/12 (an
        # error uniform over +-0.5) where the mesh does not reproduce the image
        mse = float(element_sse(elements, stats, vals).sum()) / (width * height) + 1 / 12
    return Meshed(Mesh(vertices, vals, triangles, width, height, _chains(segments)), mse, delaunay)

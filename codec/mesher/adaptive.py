"""The default mesher: the discontinuity-preserving adaptive mesher of section 3.3.2
of the paper "Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular Meshes".

Stages, each in its own module: Canny edges (codec.mesher.edges), edge polylines by the
paper's segment rule (codec.mesher.polylines), their unfolding into parallel polylines that
become the walls (codec.mesher.unfold), curvature-driven region sampling over tiles
(codec.mesher.sampling), then a constrained Delaunay triangulation with the walls as
constraint segments and the image corners included (codec.triangulate).

Beyond the paper: a vertex budget (`points`) shared between the stages, error-driven
refinement that spends what the edges and regions left over where the mesh is worst
(codec.mesher.refine: the paper's coarse-to-fine refinement of section 3.3.1, in
batches), and least-squares
vertex values (codec.mesher.values).
"""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from . import edges as edge_stage
from . import polylines as polyline_stage
from . import sampling
from . import values as vertex_values
from .. import native
from ..errors import OptionError
from ..image import structure
from ..mesh import Mesh
from ..mesh import segments as segment_pairs
from . import Finish, Meshed
from .elements import Statistics, element_sse
from .refine import FOCUSED_ROUNDS, ROUNDS, merge, refine_to_budget, run_breaks
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
    many as `budget` feet allow, most worthy first (so they win wall conflicts; ties in
    scan-line order)."""
    feet = 2 * np.diff(lines.starts)
    worth = lines.strength / np.maximum(feet, 1)
    order = np.argsort(-worth, kind="stable")
    # a stable order's prefix sums: the chosen ones are already most worthy first
    return lines.take(order[np.cumsum(feet[order]) <= budget])


def _excluded(lines: polyline_stage.Polylines, walls: Walls, shape: tuple[int, int]) -> np.ndarray:
    """Pixels on or next to the kept edges and walls: no region samples there."""
    import cv2

    mask = np.zeros(shape, dtype=np.uint8)
    mask[lines.pixels[:, 1], lines.pixels[:, 0]] = 1
    mask[walls.points[:, 1], walls.points[:, 0]] = 1
    return cv2.dilate(mask, np.ones((3, 3), np.uint8)).astype(bool)


def _off_edge_curvature(gray: np.ndarray, found: np.ndarray) -> float:
    """Share of the image's curvature energy (squared Laplacian) more than a pixel away
    from its edges."""
    import cv2

    # one compiled pass: the squared, dilated and masked images were 13 bytes a pixel
    lap = cv2.Laplacian(gray, cv2.CV_32F)
    return native._gradients.off_edge_share(lap, np.ascontiguousarray(found).view(np.uint8))


def _corners(width: int, height: int) -> np.ndarray:
    c = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], dtype=np.int64)
    return c[np.unique(c[:, 1] * width + c[:, 0], return_index=True)[1]]


def _chains(segments: np.ndarray) -> list[np.ndarray]:
    """Constraint polylines: the runs of segments that continue each other."""
    if len(segments) == 0:
        return []
    ends = np.r_[run_breaks(segments), len(segments)]
    # each run's first vertices, then its last segment's end; sliced, as np.split is
    # slow for thousands of pieces (two axis swaps each)
    flat = np.insert(segments[:, 0], ends, segments[ends - 1, 1])
    bounds = np.r_[0, ends + np.arange(1, len(ends) + 1)].tolist()
    return [flat[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def _through(finish: Finish, image: np.ndarray):
    """refine_to_budget's finish (vertices, segments) from a mesher's Finish (meshes):
    the vertices hold their pixels' values while the caller changes the mesh."""
    height, width = image.shape[:2]

    def hook(vertices: np.ndarray, segments: np.ndarray, mse: float | None):
        mesh = Mesh(vertices, vertex_values.sample(image, vertices), np.zeros((0, 3), np.int64),
                    width, height, _chains(segments))
        done = finish(mesh, mse)
        return done.vertices, segment_pairs(done.constraints)

    return hook


def build(
    image: np.ndarray,
    points: int,
    finish: Finish | None = None,
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

    segment_length, segment_error: the paper's edge polyline rule (section 3.3.2.1; pixels).
    tiles=(H, V), per_tile=(R, Z): region sampling grid and samples per tile (by default
    chosen from `points`). canny=(low, high): edge thresholds in 8-bit gray levels
    (default: automatic). edge_share, region_share: parts of the budget for the walls
    (at most) and the region samples (default: by effort, less on piecewise-smooth
    images); the rest goes to error-driven refinement. effort: 1 (quickest), 2
    (default) or 3 (lowest error per byte, about 1.5x slower): how much of the budget
    refinement places, in how many rounds.
    values: "lsq" (least squares, default) or "sample" (the pixel values, as the paper).
    Explicit tiles and per_tile are honoured even when they give more than `points`.
    finish: changes the mesh just before its last triangulation (codec.mesher.Finish).
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
        # 8-bit data is on the 255 scale already (its product by 1 would be a copy)
        walls = unfold(lines, gray if peak == 255 else gray * np.float32(255.0 / peak))
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
    # the front's image-sized planes (5 MB at 741 x 500) go before refinement makes its
    # own: an encode's peak is refinement's, and the heap above the last peak is given
    # back to the system at the end, to be faulted in again (2 us a page) by the next
    dens = found = magnitude = excluded = None
    vertices = merge(width, wall_pts, corners, samples)
    fit = None if values != "lsq" else "structure" if image.ndim == 2 else image
    layout = Statistics(image if image.ndim == 2 else gray, fit)
    vertices, segments, triangles, elements, stats, delaunay = refine_to_budget(
        gray, vertices, segments, points, layout, rounds, focused_rounds,
        None if finish is None else _through(finish, image),
    )
    if values == "lsq":
        vals = vertex_values.from_statistics(
            image, vertices, elements, stats, layout, triangles
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

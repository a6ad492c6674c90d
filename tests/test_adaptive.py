"""The adaptive (discontinuity-preserving) mesher: walls, coverage, determinism, size."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import codec
from codec.mesher import adaptive
from codec.decoder_cpu import render
from codec.errors import OptionError
from codec.mesh import doubled_areas, validate
from tests.synthetic import planar_steps, range_scene


def segments_of(m) -> np.ndarray:
    if not m.constraints:
        return np.zeros((0, 2), np.int64)
    return np.concatenate([np.stack([c[:-1], c[1:]], 1) for c in m.constraints])


def check_tiling(m) -> None:
    """Triangles tile the image exactly once: positive areas summing to (W-1)(H-1)
    doubled, every directed edge used once, and an edge without its twin lies on the
    image border."""
    validate(m)
    areas = doubled_areas(m.vertices, m.triangles)
    assert areas.min() > 0
    assert int(areas.sum()) == 2 * (m.width - 1) * (m.height - 1)
    t = m.triangles
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    keys = directed[:, 0] * len(m.vertices) + directed[:, 1]
    assert len(np.unique(keys)) == len(keys), "two triangles overlap along an edge"
    twin = directed[:, 1] * len(m.vertices) + directed[:, 0]
    lonely = directed[~np.isin(twin, keys)]
    a, b = m.vertices[lonely[:, 0]], m.vertices[lonely[:, 1]]
    on_border = ((a[:, 0] == b[:, 0]) & np.isin(a[:, 0], [0, m.width - 1])) | (
        (a[:, 1] == b[:, 1]) & np.isin(a[:, 1], [0, m.height - 1])
    )
    assert on_border.all(), "an edge inside the image has a triangle on one side only"


def check_walls_are_edges(m) -> None:
    edges = {tuple(sorted(e)) for t in m.triangles.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    for a, b in segments_of(m).tolist():
        assert tuple(sorted((a, b))) in edges


def check_no_crossings(m) -> None:
    """No two constraint segments meet anywhere but at a shared end point."""
    s = segments_of(m)
    if len(s) < 2:
        return
    i, j = np.triu_indices(len(s), 1)
    p, q, r, u = (m.vertices[x].astype(np.int64) for x in (s[i, 0], s[i, 1], s[j, 0], s[j, 1]))

    def orient(a, b, c):
        return np.sign((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))

    def between(a, b, c):  # c on the closed box of a-b
        return (np.minimum(a, b) <= c).all(1) & (c <= np.maximum(a, b)).all(1)

    o1, o2, o3, o4 = orient(p, q, r), orient(p, q, u), orient(r, u, p), orient(r, u, q)
    shared = (s[i, 0] == s[j, 0]) | (s[i, 0] == s[j, 1]) | (s[i, 1] == s[j, 0]) | (s[i, 1] == s[j, 1])
    proper = (o1 * o2 < 0) & (o3 * o4 < 0)
    # an end point inside the other segment (touching or collinear overlap)
    touch = (
        ((o1 == 0) & between(p, q, r) & (s[j, 0] != s[i, 0]) & (s[j, 0] != s[i, 1]))
        | ((o2 == 0) & between(p, q, u) & (s[j, 1] != s[i, 0]) & (s[j, 1] != s[i, 1]))
        | ((o3 == 0) & between(r, u, p) & (s[i, 0] != s[j, 0]) & (s[i, 0] != s[j, 1]))
        | ((o4 == 0) & between(r, u, q) & (s[i, 1] != s[j, 0]) & (s[i, 1] != s[j, 1]))
    )
    # two segments from one end point, running along each other
    c = np.where((s[i, 0] == s[j, 0]) | (s[i, 0] == s[j, 1]), s[i, 0], s[i, 1])
    a = np.where(s[i, 0] == c, s[i, 1], s[i, 0])
    b = np.where(s[j, 0] == c, s[j, 1], s[j, 0])
    va, vb, vc = (m.vertices[x].astype(np.int64) for x in (a, b, c))
    same = a == b
    along = shared & (o1 == 0) & (o2 == 0) & (np.einsum("ij,ij->i", va - vc, vb - vc) > 0) & ~same
    bad = proper | (touch & ~shared) | along
    assert not bad.any(), f"{bad.sum()} pairs of walls cross: {s[i[bad]].tolist()} {s[j[bad]].tolist()}"


def step_zone(image: np.ndarray, jump: int = 4) -> np.ndarray:
    """Pixels within one pixel of a step (neighbours differing by more than `jump`)."""
    import cv2

    im = image.astype(np.int64)
    step = np.zeros(image.shape, bool)
    dx = np.abs(np.diff(im, axis=1)) > jump
    dy = np.abs(np.diff(im, axis=0)) > jump
    step[:, 1:] |= dx
    step[:, :-1] |= dx
    step[1:] |= dy
    step[:-1] |= dy
    return cv2.dilate(step.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def planar_objects(width: int, height: int, seed: int, objects: int = 4) -> np.ndarray:
    """A piecewise-planar depth image: a tilted background plane and, in front of it,
    overlapping objects (convex polygons and ellipses), each a tilted plane. Levels
    are 50 apart and tilts small, so every step is at least 30 gray levels high."""
    import cv2

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    tilt = 10.0 / max(width, height)

    def plane(level):
        gx, gy = rng.uniform(-tilt, tilt, 2)
        return level + gx * (xx - width / 2) + gy * (yy - height / 2)

    levels = rng.permutation(np.arange(20, 240, 50))[: objects + 1]
    depth = plane(levels[0])
    for level in levels[1:]:
        mask = np.zeros((height, width), np.uint8)
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        r = rng.uniform(0.15, 0.35) * min(width, height)
        if rng.random() < 0.5:
            angles = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 7)))
            corners = np.stack([cx + r * np.cos(angles), cy + r * np.sin(angles)], 1)
            cv2.fillPoly(mask, [np.round(corners).astype(np.int32)], 1)
        else:
            axes = (max(2, int(r)), max(2, int(r * rng.uniform(0.4, 1.0))))
            cv2.ellipse(mask, (int(cx), int(cy)), axes, rng.uniform(0, 180), 0, 360, 1, -1)
        depth = np.where(mask > 0, plane(level), depth)
    return np.clip(np.round(depth), 0, 255).astype(np.uint8)


def check_exact_away_from_steps(m, img) -> None:
    """Every pixel more than one pixel from a step decodes to within 1 of the image."""
    err = np.abs(render(m).astype(np.int64) - img)[~step_zone(img)]
    assert err.max() <= 1, f"{(err > 1).sum()} pixels away from steps are off by up to {err.max()}"


@pytest.mark.parametrize("seed", range(4))
def test_planar_steps_are_walls_and_exact_away_from_them(seed):
    """The walls make the mesh exact away from the steps, with least-squares values
    (the default: step pixels, which no wall can follow, do not pull the vertices
    beside them) as with the pixel values (the paper's)."""
    img = planar_steps(160, 120, seed=seed)
    m = codec.build_mesh(img, points=600)
    check_tiling(m)
    assert m.constraints, "no walls on a piecewise-planar image"
    check_walls_are_edges(m)
    check_no_crossings(m)
    check_exact_away_from_steps(m, img)
    sampled = codec.build_mesh(img, points=600, values="sample")
    assert np.array_equal(sampled.vertices, m.vertices)
    check_exact_away_from_steps(sampled, img)


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(["steps", "objects"]),
    st.integers(60, 200),
    st.integers(60, 200),
    st.integers(0, 2**16),
)
def test_piecewise_planar_images_are_exact_away_from_steps(kind, width, height, seed):
    """Straight steps crossing each other, or overlapping polygons and ellipses, at a
    vertex budget of 10 % of the pixels: exact (default values) away from the steps."""
    img = planar_steps(width, height, seed=seed) if kind == "steps" else planar_objects(width, height, seed)
    m = codec.build_mesh(img, points=int(0.1 * width * height))
    check_walls_are_edges(m)
    check_exact_away_from_steps(m, img)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_range_scene_tiles_and_walls(dtype):
    img = range_scene(200, 150, seed=3, dtype=dtype)
    m = codec.build_mesh(img, points=900)
    check_tiling(m)
    check_walls_are_edges(m)
    check_no_crossings(m)
    assert m.dtype == dtype


def test_same_image_same_mesh():
    img = range_scene(160, 128, seed=5)
    a, b = codec.build_mesh(img, points=700), codec.build_mesh(img.copy(), points=700)
    assert np.array_equal(a.vertices, b.vertices)
    assert np.array_equal(a.triangles, b.triangles)
    assert np.array_equal(a.values, b.values)
    assert len(a.constraints) == len(b.constraints)
    assert all(np.array_equal(p, q) for p, q in zip(a.constraints, b.constraints))
    assert codec.encode(img, points=700) == codec.encode(img.copy(), points=700)


@pytest.mark.parametrize("n", [300, 1500, 5000])
def test_points_land_within_ten_percent(n, corpus):
    for name in ("camera", "coins"):
        img = corpus[name]
        m = codec.build_mesh(img, points=n)
        assert abs(len(m.vertices) - n) <= 0.1 * n, (name, n, len(m.vertices))
    m = codec.build_mesh(range_scene(256, 256, seed=2), points=n)
    assert abs(len(m.vertices) - n) <= 0.1 * n


def test_least_squares_beats_samples_and_uniform(corpus):
    img = corpus["camera"]
    n = int(0.01 * img.size)
    rms = {}
    for key, kw in {"lsq": {}, "sample": {"values": "sample"}, "uniform": {"mesher": "uniform"}}.items():
        out = render(codec.build_mesh(img, points=n, **kw)).astype(np.float64)
        rms[key] = np.sqrt(np.mean((out - img) ** 2))
    assert rms["lsq"] < rms["sample"] < rms["uniform"]
    assert rms["lsq"] <= 0.75 * rms["uniform"]


def test_rgb_values_per_channel():
    gray = range_scene(96, 80, seed=1)
    rgb = np.stack([gray, 255 - gray, gray // 2], axis=2)
    m = codec.build_mesh(rgb, points=400)
    assert m.values.shape == (len(m.vertices), 3)
    out = render(m).astype(np.float64)
    assert np.sqrt(np.mean((out - rgb) ** 2)) < 6


def test_seed_parameters_by_name():
    img = range_scene(128, 128, seed=4)
    m = codec.build_mesh(img, points=10, tiles=(3, 3), per_tile=(4, 4), segment_length=6, segment_error=1.5, canny=(10, 30))
    validate(m)
    assert len(m.vertices) > 10 * 3  # explicit tiles and samples are honoured


@pytest.mark.parametrize(
    "opts",
    [
        {"tiles": (0, 3)},
        {"tiles": 4},
        {"per_tile": (2, "x")},
        {"canny": (30, 10)},
        {"canny": "auto"},
        {"segment_length": 0},
        {"segment_error": -1},
        {"values": "median"},
        {"edge_share": 2},
        {"walls": True},
    ],
)
def test_bad_options_are_option_errors(opts):
    with pytest.raises(OptionError):
        codec.build_mesh(np.zeros((16, 16), np.uint8), **opts)


def _images():
    sizes = st.sampled_from([(1, 1), (2, 2), (1, 7), (9, 1), (2, 13), (3, 3), (17, 5), (24, 31), (40, 40)])
    kinds = st.sampled_from(["noise", "constant", "contrast", "steps", "stripes"])
    return st.tuples(sizes, kinds, st.sampled_from([np.uint8, np.uint16]), st.booleans(), st.integers(0, 2**16))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_images())
def test_any_image_gives_a_valid_mesh(args):
    (h, w), kind, dtype, rgb, seed = args
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    if kind == "noise":
        img = rng.integers(0, top + 1, (h, w))
    elif kind == "constant":
        img = np.full((h, w), rng.integers(0, top + 1))
    elif kind == "contrast":
        img = np.where(rng.random((h, w)) < 0.5, 0, top)
    elif kind == "steps":
        img = np.where(np.add.outer(np.arange(h), np.arange(w)) > (h + w) // 2, top, 0)
    else:
        img = np.where(np.arange(w)[None, :] % 2 == 0, top, 0).repeat(h, axis=0)
    img = img.astype(dtype)
    if rgb:
        img = np.stack([img, img[::-1], top - img], axis=2)
    m = codec.build_mesh(img, points=int(rng.integers(1, h * w + 1)))
    validate(m)
    if m.width > 1 and m.height > 1:
        check_tiling(m)
        check_no_crossings(m)
    out = codec.decode(codec.encode(img, points=max(4, len(m.vertices))))
    assert out.shape == img.shape and out.dtype == img.dtype


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**16), st.sampled_from([3, 40, 4095]), st.booleans())
def test_fast_triangulation_equals_exact(seed, extent, walls):
    """Triangle without exact arithmetic gives the exact triangulation on integer
    vertices at most 4095 apart: on a small grid (many cocircular quadruples, where
    inexact predicates would break ties differently) and far from the origin."""
    from codec.coding import canonical_triangles
    from codec.triangulate import by_triangle as triangulate

    rng = np.random.default_rng(seed)
    n = min(300, (extent + 1) ** 2 // 2)
    pts = rng.integers(0, extent + 1, (n, 2)) + rng.integers(0, 2**20, 2)
    corners = pts.min(axis=0) + np.array([[0, 0], [extent, 0], [0, extent], [extent, extent]])
    vertices = np.unique(np.r_[corners, pts], axis=0)
    segments = None
    if walls:
        tris = triangulate(vertices)
        segments = tris[rng.permutation(len(tris))[:5], :2]  # edges of one triangulation never cross
    exact = canonical_triangles(triangulate(vertices, segments, exact=True))
    assert np.array_equal(canonical_triangles(triangulate(vertices, segments)), exact)


def test_final_triangulation_is_the_one_a_decoder_rebuilds(corpus):
    """The mesher's vertices come in raster order and its triangles are the constrained
    Delaunay triangulation of them with the wall steps in their order, and it says so
    (Meshed.delaunay): codec.meshcode then stores the band without triangles and
    without triangulating again to check."""
    from codec import meshcode, triangulate as tri
    from codec.mesh import segments
    from codec.format_spec import schema

    img = corpus["camera"][:200, :300]
    meshed = adaptive.build(img, 1500)
    m = meshed.mesh
    assert meshed.delaunay
    keys = m.vertices[:, 1] * m.width + m.vertices[:, 0]
    assert (np.diff(keys) > 0).all()
    rebuilt = tri.triangulate(m.vertices, segments(m.constraints))
    assert np.array_equal(rebuilt, m.triangles)
    calls = []
    run = meshcode.triangulate

    def counted(*args):
        calls.append(1)
        return run(*args)

    try:
        meshcode.triangulate = counted
        told = meshcode.encode_band(0, m, delaunay=True)
        checked = meshcode.encode_band(0, m)
    finally:
        meshcode.triangulate = run
    assert told == checked and told["connectivity"] == schema.DELAUNAY
    assert len(calls) == 1  # only the call that checked


@pytest.mark.parametrize("name", ["camera", "moon", "scene0"])
def test_decoded_mse_matches_decoding(name, corpus):
    """The squared error the mesher reports (used for the automatic value step instead
    of decoding the band) is the decoded image's to within pixel rounding."""
    img = corpus[name]
    meshed = adaptive.build(img, round(0.01 * img.size))
    decoded = np.mean((render(meshed.mesh).astype(np.float64) - img) ** 2)
    assert abs(meshed.mse - decoded) <= 0.01 * decoded + 0.1, (meshed.mse, decoded)


def test_effort_trades_time_for_error():
    """Each effort level meets the vertex budget; effort 3 (more refinement) gives a
    lower error than the default on a photo, effort 1 a higher one; other values are
    refused."""
    from skimage import data

    img = data.camera()
    errors = {}
    for effort in (1, 2, 3):
        m = codec.build_mesh(img, points=2500, effort=effort)
        assert abs(len(m.vertices) - 2500) <= 250
        errors[effort] = float(np.sqrt(np.mean((render(m).astype(float) - img) ** 2)))
    assert errors[3] < errors[2] < errors[1]
    for bad in (0, 4, 2.0, True, "3"):
        with pytest.raises(OptionError, match="effort"):
            codec.build_mesh(img, points=500, effort=bad)


def test_piecewise_smooth_images_are_told_from_photos():
    """Range images keep their curvature on their edges, photos do not: the former
    get the smaller region share by default."""
    from skimage import data

    from codec.mesher import edges
    from codec.image import structure

    def off_edges(img):
        gray = structure(img)
        found, _, _ = edges.detect(gray, float(np.iinfo(img.dtype).max), None)
        return adaptive._off_edge_curvature(gray, found)

    for seed in range(3):
        assert off_edges(range_scene(200, 150, seed=seed)) < adaptive.SMOOTH_OFF_EDGES
        assert off_edges(range_scene(200, 150, seed=seed, dtype=np.uint16)) < adaptive.SMOOTH_OFF_EDGES
    for photo in (data.camera(), data.moon(), data.coins()):
        assert off_edges(photo) > 2 * adaptive.SMOOTH_OFF_EDGES


@pytest.mark.parametrize("per_tile", [(1, 2**62), (2, 2**61), (2**40, 2**30)])
def test_per_tile_asking_for_more_samples_than_can_be_held_is_refused(per_tile):
    """The sampling kernel sizes its buffers from tiles x per_tile: products that wrapped
    int64 made tiny buffers and a crash (SIGSEGV), now an OptionError naming the option."""
    img = np.zeros((64, 64), np.uint8)
    img[:, 32:] = 200
    with pytest.raises(codec.OptionError, match="per_tile"):
        codec.encode(img, tiles=(4, 1), per_tile=per_tile)
    from codec import native

    dens = np.ones((8, 8))
    bounds = np.array([0, 8], np.int64)
    with pytest.raises(ValueError, match="more samples"):
        native._gradients.tile_samples(dens, bounds, bounds, per_tile[0], per_tile[1])

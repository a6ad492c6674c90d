"""Regenerate the conformance files: python format_spec/conformance/make.py

Each `.atm` here is written by the reference codec and its `.png` is the image a
conforming decoder must produce. Run this only when the format version changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import codec
from codec import canonical, container, encoder
from codec.coding import canonical_triangles
from codec.files import write_image
from codec.mesh import Mesh, segments
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


def lattice_mesh(w: int, h: int, step: int, values, walls=(), extra=()) -> Mesh:
    """A mesh of every `step`-th pixel (and the last row and column) plus `extra`
    points, its polylines `walls` given as point lists, gray values from values(x, y):
    almost every free edge of such a mesh is a tie (its quadrilateral a rectangle)."""
    gx, gy = np.meshgrid(np.r_[0:w:step, w - 1], np.r_[0:h:step, h - 1])
    points = [np.stack([gx.ravel(), gy.ravel()], 1), np.asarray(list(extra), np.int64).reshape(-1, 2)]
    points += [np.asarray(line, np.int64) for line in walls]
    vertices = np.unique(np.concatenate(points), axis=0)
    index = {tuple(p): i for i, p in enumerate(vertices.tolist())}
    lines = [np.array([index[tuple(p)] for p in line]) for line in walls]
    triangles = triangulate(vertices, segments(lines) if lines else None)
    v = np.clip(np.rint(values(vertices[:, 0], vertices[:, 1])), 0, 255).astype(np.uint8)
    return Mesh(vertices, v, triangles, w, h, lines)


def saddle(x, y):
    """Values that are not planar over a lattice square, so its diagonal shows."""
    return 128 + 0.09 * (x - 20.0) * (y - 14.0) + 30 * np.sin(x * 0.7) * np.cos(y * 0.5)


def rings_mesh() -> Mesh:
    """96x96 gray: concentric rings of lattice points that are exactly cocircular
    (x^2 + y^2 = r^2 around (48, 48) has 12 to 32 integer solutions for these r^2), the
    centre and the corners: ties of many points at once, not just of four."""
    c = 48
    ring = [
        (x, y)
        for r2 in (25, 100, 325, 625, 1105, 2025)
        for x in range(-47, 48)
        for y in range(-47, 48)
        if x * x + y * y == r2
    ]
    points = np.array(ring + [(0, 0)]) + c
    corners = np.array([[0, 0], [95, 0], [0, 95], [95, 95]])
    vertices = np.unique(np.concatenate([points, corners]), axis=0)
    triangles = triangulate(vertices)
    x, y = vertices[:, 0] - c, vertices[:, 1] - c
    v = 120 + 0.04 * (x * x - y * y) + 40 * np.sign(x * y) * np.sqrt(np.abs(x * y)) / 10
    return Mesh(vertices, np.clip(np.rint(v), 0, 255).astype(np.uint8), triangles, 96, 96)


def walls_in_ties() -> Mesh:
    """48x32 gray: a lattice of step 2 with walls through its ties: a vertical wall
    (x = 20 | x = 21, so 1x2 rectangles beside it tie too), a wall along the lattice
    diagonal that the tie rule would not choose, and one of (4, 2) steps."""
    left = [(20, y) for y in range(0, 32, 2)]
    right = [(21, y) for y in range(0, 32, 2)]
    diagonal = [(24 + k, 2 + k) for k in range(0, 20, 2)]
    knight = [(26, 30), (30, 28), (34, 26), (38, 24), (42, 22), (46, 20)]
    step = lambda x, y: np.where(x <= 20, saddle(x, y), 60 + 2 * y + 0.5 * x)
    return lattice_mesh(48, 32, 2, step, walls=[left, right, diagonal, knight])


def flipped(mesh: Mesh, rng: np.random.Generator, delaunay: bool) -> Mesh:
    """The mesh with a set of non-adjacent free edges flipped where their quadrilateral
    is strictly convex: ties only (delaunay=True: another Delaunay tiling, just not the
    one of the tie rule) or any (a tiling that is not Delaunay). Listed in its file."""
    walls = segments(mesh.constraints) if mesh.constraints else None
    tris = canonical.random_flips(mesh.vertices, mesh.triangles, walls, rng, 0.7, ties_only=delaunay)
    return Mesh(mesh.vertices, mesh.values, tris, mesh.width, mesh.height, mesh.constraints)


def describe(data: bytes) -> str:
    """Per file: free edges, exact ties among them, and bands whose triangles are not
    the canonical triangulation (so listed)."""
    listed = free = ties = 0
    for _, m in container.unpack(data)[1]:
        walls = segments(m.constraints) if m.constraints else None
        f, t = canonical.tie_count(m.vertices, m.triangles, walls)
        free, ties = free + f, ties + t
        ours = canonical_triangles(m.triangles)
        rebuilt = canonical_triangles(triangulate(m.vertices, walls))
        listed += ours.shape != rebuilt.shape or bool((ours != rebuilt).any())
    return f"{free} free edges, {ties} exact ties, {listed} listed bands"


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
    # signed integers (sample types 3-5): negative values, holes marked by a sample
    # value of the type (NDAT), stored exactly as u16 plus QUNT's whole-number offset
    signed = synthetic.range_scene(40, 30, seed=12).astype(np.int64)
    int8 = (signed - 128).astype(np.int8)
    int8[3:9, 5:14] = -128
    cases["int8_holes"] = codec.encode(int8, mesher="uniform", points=120, nodata=-128)
    dem = synthetic.range_scene(48, 32, seed=13).astype(np.int64) * 40 - 3000
    dem[20:26, 30:41] = -32768  # voids, as in SRTM tiles
    cases["int16_dem_holes"] = codec.encode(dem.astype(np.int16), points=160, nodata=-32768)
    deep = synthetic.range_scene(40, 30, seed=14).astype(np.int64) * 100 - 2_000_000
    deep[12:16, :7] = -(2**31)
    cases["int32_bands_holes"] = codec.encode(
        deep.astype(np.int32), mesher="uniform", points=150, band_height=12, nodata=-(2**31)
    )
    # an H x W x 1 array: the `axis` chunk (after NDAT) keeps its trailing axis
    column = synthetic.range_scene(32, 24, seed=15)[:, :, None].copy()
    column[5:9, 20:27] = 0
    cases["axis_gray8_holes"] = codec.encode(column, mesher="uniform", points=90, nodata=0)
    lattice = lattice_mesh(41, 31, 2, saddle)
    rng = np.random.default_rng(19)
    cases["lattice_ties"] = encoder.pack(lattice)
    cases["rings_ties"] = encoder.pack(rings_mesh())
    cases["walls_ties"] = encoder.pack(walls_in_ties())
    cases["listed_ties"] = encoder.pack(flipped(lattice, rng, delaunay=True))
    scene = codec.build_mesh(synthetic.range_scene(64, 48, seed=11), points=160)
    cases["listed_not_delaunay"] = encoder.pack(flipped(scene, rng, delaunay=False))
    # the residual layer (§4.8): lossless 16-bit depth with holes over bands, and
    # near-lossless RGB (every sample within 2)
    depth16 = synthetic.range_scene(40, 30, seed=12, dtype=np.uint16)
    depth16[5:12, 8:20] = 0
    # (their preview meshes are uniform lattices, so that their bands have exact ties)
    cases["residual_depth16"] = codec.encode(depth16, lossless=True, nodata=0, band_height=8, points=120,
                                             mesher="uniform")
    cases["residual_rgb8"] = codec.encode(
        np.random.default_rng(13).integers(0, 256, (16, 24, 3), dtype=np.uint8), max_error=2, residual=True,
        band_height=6, points=60, mesher="uniform",
    )
    # lossless float (§4.10): binary32 keys with -0, infinities, a subnormal and a NaN
    # with a payload as samples, NaN holes over bands; and depths in millimetres as
    # metres, whole numbers of a step, through sample_type 2 with a lossless layer
    rng = np.random.default_rng(21)
    exact = (synthetic.range_scene(40, 30, seed=21).astype(np.float64) * 0.0137 + 1.25
             + rng.normal(0, 0.002, (30, 40))).astype(np.float32)
    exact[6:13, 9:21] = np.nan
    exact.view(np.uint32)[0, :6] = [0x80000000, 0x7F800000, 0xFF800000, 0x00000001, 0x7FC12345, 0xFFC00000]
    cases["exact_float32_holes"] = codec.encode(exact, lossless=True, band_height=12, points=120, mesher="uniform")
    millimetres = (synthetic.range_scene(36, 24, seed=22).astype(np.float64) * 7 + 800) / 1000
    millimetres[3:8, 20:30] = np.nan
    cases["steps_float_lossless"] = codec.encode(millimetres.astype(np.float32), lossless=True, band_height=10,
                                                 points=90, mesher="uniform")
    centimetres = synthetic.range_scene(40, 30, seed=23).astype(np.float64) * 7.9 + 1000.0
    centimetres = np.round((centimetres + np.random.default_rng(23).integers(-40, 40, (30, 40)) / 100) * 100) / 100
    centimetres[2:6, 3:11] = np.nan
    cases["steps32_float_lossless"] = codec.encode(centimetres.astype(np.float32), lossless=True, band_height=16,
                                                   points=90, mesher="uniform")
    # context-coded holes (§4.11): ragged dropouts in the upper bands' HOLE chunks, a
    # band without holes keeping its MASK chunk (a file may mix them)
    speckled = synthetic.range_scene(40, 30, seed=16, dtype=np.uint16)
    speckled[:18][np.random.default_rng(16).random((18, 40)) < 0.25] = 0
    speckled[2:7, 30:38] = 0
    cases["holes_context16"] = codec.encode(speckled, mesher="uniform", points=120, band_height=12, nodata=0)
    # `make.py NAME ...` writes only those files (the others keep their bytes)
    chosen = set(sys.argv[1:]) or set(cases)
    for name, data in cases.items():
        if name not in chosen:
            continue
        (HERE / f"{name}.atm").write_bytes(data)
        image = codec.decode(data)
        if image.dtype.kind in "fi" or image.shape[2:] == (1,):  # beyond PNG: float, signed, H x W x 1
            np.save(HERE / f"{name}.npy", image)
        else:
            write_image(HERE / f"{name}.png", image)
        print(name, codec.info(data), describe(data), sep="\n  ")


if __name__ == "__main__":
    main()

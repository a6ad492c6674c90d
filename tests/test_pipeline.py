"""The band pipeline does each piece of work once: Triangle runs only for the mesher's
rounds and once more in a band whose shared rows change, and the stored order, sample
order and parents of a band are built once for quantising and writing it."""

from __future__ import annotations

import contextlib
import functools

import numpy as np
import pytest
import triangle

import codec
from codec import meshcode, mesher
from tests.synthetic import range_scene


@contextlib.contextmanager
def counting(module, name: str):
    """Count the calls of module.name while inside."""
    calls = []
    real = getattr(module, name)

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    setattr(module, name, counted)
    try:
        yield calls
    finally:
        setattr(module, name, real)


@contextlib.contextmanager
def mesher_calls():
    """Count Triangle runs inside the meshers' build() separately: (all, in meshers)."""
    inside = []
    real_builder = mesher.builder

    def builder(name):
        build = real_builder(name)

        @functools.wraps(build)  # the pipeline reads build()'s defaults
        def counted(*args, **kwargs):
            with counting(triangle, "triangulate") as calls:
                out = build(*args, **kwargs)
            inside.append(len(calls))
            return out

        return counted

    mesher.builder = builder
    import codec.pipeline as pipeline

    pipeline.builder = builder
    try:
        with counting(triangle, "triangulate") as total:
            yield total, inside
    finally:
        mesher.builder = pipeline.builder = real_builder


@pytest.mark.parametrize("mesher_name", ["adaptive", "uniform"])
def test_one_band_runs_triangle_only_in_the_mesher(mesher_name):
    image = range_scene(160, 120, seed=4)
    with mesher_calls() as (total, inside):
        codec.encode(image, points=500, mesher=mesher_name)
    assert len(inside) == 1 and len(total) == inside[0] and inside[0] >= 1


def test_bands_run_triangle_once_more_for_their_shared_rows():
    image = range_scene(160, 120, seed=4)
    with mesher_calls() as (total, inside):
        data = codec.encode(image, points=600, band_height=20)
    bands = codec.info(data)["bands"]
    assert len(inside) == bands == 6
    # the first band samples its last row, the middle ones pin their first row (and
    # measure it: one run) and sample their last, the last band pins its first row
    assert len(total) - sum(inside) <= 1 + 2 * (bands - 2) + 1


def test_holes_run_triangle_once_to_cut_them():
    image = range_scene(160, 120, seed=4)
    mask = np.zeros(image.shape, bool)
    mask[40:70, 50:90] = True
    with mesher_calls() as (total, inside):
        codec.encode(image, points=500, mask=mask)
    assert len(total) == inside[0] + 1


def test_stored_and_sample_order_are_built_once_per_band():
    image = range_scene(160, 120, seed=4)
    with counting(meshcode, "_sample_order") as orders, counting(meshcode, "sample_parents") as parents:
        codec.encode(image, points=500)
    assert len(orders) == len(parents) == 1


def test_code_band_is_pure():
    """The same band in gives the same coded band out, and the input is not touched."""
    from codec import pipeline
    from codec.settings import Settings

    image = range_scene(96, 64, seed=2)
    plan = pipeline.plan(Settings(points=300), 96, 64)
    rows = image[:33].copy()
    top = (np.array([0, 40, 95]), np.array([10, 20, 30], np.uint8))
    a = pipeline.code_band(rows, None, plan, y0=31, top=top, last=False, step=None)
    b = pipeline.code_band(rows, None, plan, y0=31, top=top, last=False, step=None)
    np.testing.assert_array_equal(rows, image[:33])
    assert a.step == b.step and a.delaunay == b.delaunay
    for field in ("vertices", "values", "triangles"):
        np.testing.assert_array_equal(getattr(a.mesh, field), getattr(b.mesh, field))
    # the pinned row is the one given, exactly
    first = a.mesh.vertices[:, 1] == 0
    np.testing.assert_array_equal(a.mesh.vertices[first, 0], top[0])
    np.testing.assert_array_equal(a.mesh.values[first], top[1])
    keys = a.mesh.vertices[:, 1] * 96 + a.mesh.vertices[:, 0]
    assert (np.diff(keys) > 0).all()  # stored order


@pytest.mark.parametrize(
    "options",
    [dict(points=500), dict(points=600, band_height=20), dict(quality=70), dict(max_error=6, band_height=30),
     dict(points=500, mesher="uniform"), dict(points=400, mask="holes")],
)
def test_the_writer_never_triangulates_again(options):
    """Every stage that changes a band's triangles makes them as a decoder rebuilds
    them and says so, so the MESH chunk is written without a second triangulation."""
    image = range_scene(160, 120, seed=4)
    if options.get("mask") == "holes":
        options = dict(options, mask=np.zeros(image.shape, bool))
        options["mask"][40:70, 50:90] = True
    real = meshcode.encode_band
    runs = []

    def encode_band(*args, **kwargs):
        with counting(triangle, "triangulate") as calls:
            out = real(*args, **kwargs)
        runs.append(len(calls))
        return out

    meshcode.encode_band = encode_band
    try:
        codec.encode(image, **options)
    finally:
        meshcode.encode_band = real
    assert runs and not any(runs)

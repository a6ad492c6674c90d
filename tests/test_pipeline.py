"""The band pipeline does each piece of work once: a band is triangulated only in the
mesher's rounds, once a round (its holes and shared rows go in before the mesher's
last triangulation), and the stored order, sample order and parents of a band are
built once for quantising and writing it."""

from __future__ import annotations

import contextlib
import functools

import importlib
import sys

import numpy as np
import pytest

import codec
import codec.triangulate
from codec import meshcode, mesher
from codec.mesher.adaptive import EFFORTS
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
def triangulations():
    """Count the calls of codec's own triangulate (whatever library is behind it), in
    every codec module that holds it, and the triangulations an incremental
    codec.triangulate.Triangulation gives out (one a refinement round: its triangles(),
    or the slots dirty() reports where refinement keeps it by slot)."""
    real = codec.triangulate.triangulate
    incremental = codec.triangulate.Triangulation
    real_triangles = incremental.triangles
    real_dirty = incremental.dirty
    for name in ("codec.pipeline", "codec.meshcode", "codec.holes", "codec.mesher.adaptive", "codec.mesher.uniform"):
        importlib.import_module(name)
    holders = [m for n, m in list(sys.modules.items()) if n.startswith("codec") and getattr(m, "triangulate", None) is real]
    calls = []

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    def triangles(self):
        calls.append(1)
        return real_triangles(self)

    def dirty(self, *args, **kwargs):
        calls.append(1)
        return real_dirty(self, *args, **kwargs)

    for m in holders:
        m.triangulate = counted
    incremental.triangles = triangles
    incremental.dirty = dirty
    try:
        yield calls
    finally:
        for m in holders:
            m.triangulate = real
        incremental.triangles = real_triangles
        incremental.dirty = real_dirty


@contextlib.contextmanager
def mesher_calls():
    """Count triangulations inside the meshers' build() separately: (all, in meshers)."""
    inside = []
    real_builder = mesher.builder

    def builder(name):
        build = real_builder(name)

        @functools.wraps(build)  # the pipeline reads build()'s defaults
        def counted(*args, **kwargs):
            with triangulations() as calls:
                out = build(*args, **kwargs)
            inside.append(len(calls))
            return out

        return counted

    mesher.builder = builder
    import codec.pipeline as pipeline

    pipeline.builder = builder
    try:
        with triangulations() as total:
            yield total, inside
    finally:
        mesher.builder = pipeline.builder = real_builder


@pytest.mark.parametrize("mesher_name", ["adaptive", "uniform"])
def test_one_band_runs_triangle_only_in_the_mesher(mesher_name):
    image = range_scene(160, 120, seed=4)
    with mesher_calls() as (total, inside):
        codec.encode(image, points=500, mesher=mesher_name)
    assert len(inside) == 1 and len(total) == inside[0] and inside[0] >= 1


@pytest.mark.parametrize("mesher_name", ["adaptive", "uniform"])
def test_bands_are_triangulated_once_a_round(mesher_name):
    # issue #18: the shared rows used to cost two more triangulations in a middle band
    # (one to measure the pinned first row, one after pinning), one in the first and
    # the last
    image = range_scene(160, 120, seed=4)
    with mesher_calls() as (total, inside):
        data = codec.encode(image, points=600, band_height=20, mesher=mesher_name)
    bands = codec.info(data)["bands"]
    assert len(inside) == bands == 6
    assert len(total) == sum(inside)
    # the adaptive mesher: once for each of at most its longest rounds, and once after
    rounds = max(max(r, f) for _, r, f in EFFORTS.values()) if mesher_name == "adaptive" else 0
    assert max(inside) <= rounds + 1


@pytest.mark.parametrize("band_height", [None, 30])
def test_holes_are_cut_in_the_meshers_last_triangulation(band_height):
    image = range_scene(160, 120, seed=4)
    mask = np.zeros(image.shape, bool)
    mask[40:70, 50:90] = True
    with mesher_calls() as (total, inside):
        data = codec.encode(image, points=500, mask=mask, nodata=255, band_height=band_height)
    assert len(total) == sum(inside)
    out = codec.decode(data)
    assert (out[mask] == 255).all()


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
    [dict(points=500), dict(points=600, band_height=20), dict(quality=70), dict(max_error=6, band_height=30, residual=False),
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
        with triangulations() as calls:
            out = real(*args, **kwargs)
        runs.append(len(calls))
        return out

    meshcode.encode_band = encode_band
    try:
        codec.encode(image, **options)
    finally:
        meshcode.encode_band = real
    assert runs and not any(runs)


def test_a_band_whose_last_triangulation_fails_is_made_in_turns():
    """Where the mesher's last triangulation refuses the band's walls (a wall that
    crosses a rim in a way only the triangulation finds), the band is meshed without
    its holes and rows, then cut and pinned: still a valid band with its holes exact
    and its shared rows equal."""
    from codec import pipeline
    from codec.errors import ATMError

    image = range_scene(160, 120, seed=4)
    mask = np.zeros(image.shape, bool)
    mask[40:70, 50:90] = True
    expected_rows = codec.decode(codec.encode(image, points=600, mask=mask, nodata=255, band_height=30))
    real = pipeline.builder
    refused = []

    def builder(name):
        build = real(name)

        @functools.wraps(build)
        def strict(image, points, finish=None, **options):
            if finish is not None:
                refused.append(1)
                raise ATMError("constraint segments cross each other")
            return build(image, points, None, **options)

        return strict

    pipeline.builder = builder
    try:
        data = codec.encode(image, points=600, mask=mask, nodata=255, band_height=30)
    finally:
        pipeline.builder = real
    assert refused
    out = codec.decode(data)
    assert (out[mask] == 255).all()
    # a shared row decodes the same in both bands that hold it
    from codec import container
    from codec.decoder_cpu import render

    _, bands = container.unpack(data)
    for (_, above), (_, below) in zip(bands, bands[1:]):
        np.testing.assert_array_equal(render(above)[-1], render(below)[0])
    # and the bands made in turns are about as close to the image as made at once
    valid = ~mask
    err = lambda a: np.sqrt(np.mean((a[valid].astype(float) - image[valid]) ** 2))  # noqa: E731
    assert err(out) <= 1.5 * err(expected_rows)

"""Local least squares during refinement to a bound: codec.mesher.values.refit moves
only the vertices it is told to, and refinement refits only what a round changed."""

from __future__ import annotations

import numpy as np

import codec
from codec import decoder_cpu, error_bound
from codec.mesh import Mesh
from codec.mesher import values as vertex_values
from codec.triangulate import triangulate


def random_mesh(image: np.ndarray, count: int, seed: int = 0):
    h, w = image.shape[:2]
    rng = np.random.default_rng(seed)
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]])
    pts = np.c_[rng.integers(0, w, count), rng.integers(0, h, count)]
    vertices = np.unique(np.r_[pts, corners], axis=0)
    return vertices, triangulate(vertices, np.zeros((0, 2), np.int64))


def squared_error(image, vertices, triangles, values) -> float:
    h, w = image.shape[:2]
    out = decoder_cpu.render(Mesh(vertices, values, triangles, w, h, [], None))
    return float(((out.astype(np.float64) - image) ** 2).sum())


def test_refit_of_every_vertex_is_the_global_fit(corpus):
    image = corpus["camera"]
    vertices, triangles = random_mesh(image, 2000)
    whole = vertex_values.fit(image, vertices, triangles, "lsq")
    local = vertex_values.refit(image, vertices, triangles, vertex_values.sample(image, vertices),
                                np.ones(len(vertices), bool))
    assert np.array_equal(local, whole)


def test_refit_moves_only_free_vertices_and_lowers_the_error(corpus):
    for image in (corpus["camera"], corpus["astronaut"]):
        vertices, triangles = random_mesh(image, 1500, seed=1)
        start = vertex_values.sample(image, vertices)
        free = np.random.default_rng(2).random(len(vertices)) < 0.2
        out = vertex_values.refit(image, vertices, triangles, start, free)
        assert out.dtype == image.dtype and out.shape == start.shape
        assert np.array_equal(out[~free], start[~free])
        assert not np.array_equal(out[free], start[free])
        assert squared_error(image, vertices, triangles, out) < squared_error(image, vertices, triangles, start)


def test_refinement_refits_only_what_each_round_changed(corpus, monkeypatch):
    shares = []
    refit = vertex_values.refit

    def recording(image, vertices, triangles, previous, free, layout=None):
        shares.append(free.mean())
        return refit(image, vertices, triangles, previous, free, layout)

    def no_global_fit(*args, **kwargs):
        raise AssertionError("refinement refitted the whole mesh")

    monkeypatch.setattr(error_bound.vertex_values, "refit", recording)
    monkeypatch.setattr(error_bound.vertex_values, "fit", no_global_fit)
    image = corpus["camera"][:200, :200]
    out = codec.decode(codec.encode(image, max_error=6))
    assert np.abs(out.astype(int) - image).max() <= 6
    assert len(shares) > 3
    # the late rounds add few vertices: a small part of the mesh is refitted
    assert min(shares) < 0.2


def test_a_max_error_bound_takes_fewer_rounds(corpus, monkeypatch):
    # camera's top-left corner at max_error=6 took 76 rounds when the last pixels
    # beside walls waited a round each (60 now)
    rounds = []
    measure = error_bound._squared_errors
    monkeypatch.setattr(error_bound, "_squared_errors", lambda *a: rounds.append(1) or measure(*a))
    image = corpus["camera"][:200, :200]
    out = codec.decode(codec.encode(image, max_error=6))
    assert np.abs(out.astype(int) - image).max() <= 6
    assert len(rounds) <= 64

"""Shared test helpers: random meshes, a file's chunks and the public corpus."""

from __future__ import annotations

import os
import struct

import numpy as np
import pytest

from codec import decoder_gl
from codec.errors import BackendError
from codec.mesh import Mesh
from codec.triangulate import triangulate


@pytest.fixture(scope="module")
def gl() -> None:
    """Require a GL context: fail in CI (CI set), skip elsewhere."""
    try:
        decoder_gl.context()
    except BackendError as exc:
        if os.environ.get("CI"):
            pytest.fail(f"CI must test the OpenGL decoder: {exc}")
        pytest.skip(str(exc))


@pytest.fixture
def no_gl(monkeypatch) -> None:
    """A machine where no GL context can be made: EGL fails, and no context is cached."""
    import moderngl

    def no_egl(**kwargs):
        raise Exception("eglGetDisplay failed")

    monkeypatch.setattr(decoder_gl, "_state", None)
    monkeypatch.setattr(decoder_gl, "_failure", None)
    monkeypatch.setattr(moderngl, "create_standalone_context", no_egl)


def chunks(data: bytes) -> list[tuple[int, bytes, bytes]]:
    """(offset, type, payload) of each chunk of a well-formed file."""
    out, pos = [], 10
    while pos < len(data):
        length, ctype = struct.unpack_from("<I4s", data, pos)
        out.append((pos, ctype, data[pos + 8 : pos + 8 + length]))
        pos += 12 + length
    return out


def random_mesh(seed: int, width: int, height: int, *, dtype=np.uint8, channels: int = 1,
                extra: int = 10, walls: bool = True) -> Mesh:
    """A valid mesh of a width x height image: the corners plus `extra` random vertices,
    Delaunay-triangulated, random values, and some triangle edges kept as polylines."""
    rng = np.random.default_rng(seed)
    xs = np.array([0, width - 1, 0, width - 1])
    ys = np.array([0, 0, height - 1, height - 1])
    n = min(extra, width * height)
    pts = np.stack([np.r_[xs, rng.integers(0, width, n)], np.r_[ys, rng.integers(0, height, n)]], 1)
    vertices = np.unique(pts, axis=0)
    if width == 1 or height == 1:
        triangles = np.zeros((0, 3), np.int64)
    else:
        triangles = triangulate(vertices)
    top = np.iinfo(dtype).max
    shape = (len(vertices),) if channels == 1 else (len(vertices), channels)
    values = rng.integers(0, top + 1, shape, dtype=np.int64).astype(dtype)
    constraints = []
    if walls and len(triangles):
        for t in triangles[rng.permutation(len(triangles))[: rng.integers(0, 4)]]:
            constraints.append(np.array([t[0], t[1], t[2]]) if rng.random() < 0.5 else t[:2].copy())
    return Mesh(vertices, values, triangles, width, height, constraints)


@pytest.fixture(scope="session")
def corpus() -> dict[str, np.ndarray]:
    """The public test corpus (tests/corpus.py), as uint8 gray arrays."""
    from tests.synthetic import range_scene
    from tests.corpus import load_corpus

    images = load_corpus()
    images["scene0"] = range_scene(256, 256, seed=0)
    return images

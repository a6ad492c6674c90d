"""Mesh export (codec.export) and `atm mesh`: OBJ, PLY, SVG and the overlay PNG."""

from __future__ import annotations

import re

import numpy as np
import pytest

import codec
from codec import export
from codec.decoding import render
from codec.files import read_image
from tests.conftest import random_mesh
from tests.test_cli import atm


@pytest.fixture(scope="module")
def atm_file(tmp_path_factory):
    from tests.synthetic import range_scene

    path = tmp_path_factory.mktemp("export") / "scene.atm"
    codec.write(path, range_scene(60, 40, seed=3), points=250)
    return path


def test_obj_has_one_v_line_per_vertex_and_1_based_faces():
    m = random_mesh(1, 30, 20, extra=40)
    text = export.to_obj(m).decode()
    v = [line.split() for line in text.splitlines() if line.startswith("v ")]
    f = [line.split() for line in text.splitlines() if line.startswith("f ")]
    walls = [line for line in text.splitlines() if line.startswith("l ")]
    assert len(v) == len(m.vertices) and len(f) == len(m.triangles)
    np.testing.assert_array_equal(np.array(v)[:, 1:3].astype(int), m.vertices)
    np.testing.assert_allclose(np.array(v)[:, 3].astype(float), m.values, rtol=1e-6)
    np.testing.assert_array_equal(np.array(f)[:, 1:].astype(int) - 1, m.triangles)
    assert len(walls) == len(m.constraints)


def test_obj_of_rgb_carries_vertex_colours():
    m = random_mesh(2, 10, 10, channels=3)
    v = [line.split() for line in export.to_obj(m).decode().splitlines() if line.startswith("v ")]
    assert all(len(row) == 7 for row in v)
    np.testing.assert_allclose(np.array(v)[:, 4:].astype(float), m.values / 255, atol=1e-5)


def test_ply_header_and_body_agree():
    m = random_mesh(3, 25, 15, extra=30)
    data = export.to_ply(m)
    head, body = data.split(b"end_header\n", 1)
    counts = dict(re.findall(r"element (\w+) (\d+)", head.decode()))
    assert int(counts["vertex"]) == len(m.vertices) and int(counts["face"]) == len(m.triangles)
    walls = export.wall_segments(m)
    assert int(counts["edge"]) == len(walls)
    assert len(body) == 12 * len(m.vertices) + 13 * len(m.triangles) + 8 * len(walls)
    xyz = np.frombuffer(body[: 12 * len(m.vertices)], "<f4").reshape(-1, 3)
    np.testing.assert_array_equal(xyz[:, :2], m.vertices)


def test_svg_draws_every_edge_once_and_the_walls():
    m = random_mesh(4, 20, 20, extra=25)
    svg = export.to_svg(m)
    edges_d = re.search(r'id="edges" d="([^"]*)"', svg).group(1)
    walls_d = re.search(r'id="walls" d="([^"]*)"', svg).group(1)
    assert edges_d.count("M") == len(export.unique_edges(m))
    assert walls_d.count("M") == len(export.wall_segments(m))
    assert 'viewBox="0 0 20 20"' in svg


def test_overlay_draws_over_the_decoded_image():
    m = random_mesh(5, 40, 30, extra=20)
    base = export.display_rgb(render(m))
    out = export.overlay_png(m, scale=2)
    assert out.shape == (60, 80, 3) and out.dtype == np.uint8
    enlarged = np.repeat(np.repeat(base, 2, 0), 2, 1)
    changed = (out != enlarged).any(axis=2)
    assert 0.02 < changed.mean() < 0.9  # lines drawn, image still there
    # a vertex's pixel lies on its edges' lines
    x, y = m.vertices[-1]
    assert changed[2 * y : 2 * y + 2, 2 * x : 2 * x + 2].any()


def test_sixteen_bit_and_float_images_are_stretched_for_display():
    ramp = np.arange(12, dtype=np.uint16).reshape(3, 4) * 100 + 1000
    shown = export.display_rgb(ramp)
    assert shown.shape == (3, 4, 3) and shown.min() == 0 and shown.max() == 255
    holes = np.array([[np.nan, 1.0], [2.0, 3.0]], np.float32)
    assert export.display_rgb(holes)[0, 0].tolist() == [0, 0, 0]


def test_atm_mesh_writes_all_four_outputs(atm_file, tmp_path):
    m = codec.decode_mesh(atm_file.read_bytes())
    for ext in ("obj", "ply", "svg", "png"):
        out = tmp_path / f"m.{ext}"
        r = atm("mesh", atm_file, out)
        assert r.returncode == 0, r.stderr
        assert out.stat().st_size > 0
    text = (tmp_path / "m.obj").read_text()
    assert sum(line.startswith("v ") for line in text.splitlines()) == len(m.vertices)
    assert (tmp_path / "m.ply").read_bytes().startswith(b"ply\n")
    assert "<svg" in (tmp_path / "m.svg").read_text()
    png = read_image(tmp_path / "m.png")
    scale = export.auto_scale(60, 40)
    assert png.shape == (40 * scale, 60 * scale, 3)


def test_atm_mesh_refuses_unknown_formats_and_bad_input(atm_file, tmp_path):
    r = atm("mesh", atm_file, tmp_path / "m.txt")
    assert r.returncode == 1 and b"use .obj, .ply, .svg, .png or .terrain" in r.stderr
    (tmp_path / "junk.atm").write_bytes(b"junk")
    r = atm("mesh", tmp_path / "junk.atm", tmp_path / "m.obj")
    assert r.returncode == 1 and r.stderr.startswith(b"atm: error:")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.atm"]

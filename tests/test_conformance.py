"""The conformance files of format_spec/ decode to their expected images exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import codec
from codec import frames
from codec.decoding import render
from codec.files import read_image
from codec.format_spec import schema
from tests.conftest import chunks

VECTORS = Path(__file__).resolve().parent.parent / "format_spec" / "conformance"
CASES = sorted(p.stem for p in VECTORS.glob("*.atm"))


def test_there_are_conformance_files():
    assert {"gray8_steps", "gray16_scene", "rgb8_grid", "line_1x9", "bands_gray8", "float_elevation", "holes_float", "walls_hilbert",
            "lattice_ties", "rings_ties", "walls_ties", "listed_ties", "listed_not_delaunay",
            "int8_holes", "int16_dem_holes", "int32_bands_holes", "axis_gray8_holes",
            "residual_depth16", "residual_rgb8", "exact_float32_holes", "steps_float_lossless",
            "steps32_float_lossless", "holes_context16"} <= set(CASES)


@pytest.mark.parametrize("name", CASES)
def test_decodes_exactly(name):
    data = (VECTORS / f"{name}.atm").read_bytes()
    npy = VECTORS / f"{name}.npy"
    expected = np.load(npy) if npy.exists() else read_image(VECTORS / f"{name}.png")
    out = codec.decode(data)
    assert out.dtype == expected.dtype
    np.testing.assert_array_equal(out, expected)  # NaN where expected has NaN


def test_conformance_files_store_positions_both_ways():
    """Both position orders of a MESH chunk (ATM.md §4.2.2) are exercised by a file."""
    orders = {
        schema.MeshPayload.parse(frames.decompress(payload, 1 << 30, "MESH"), sample_type=0, channels=1).position_order
        for name in CASES
        for _, kind, payload in chunks((VECTORS / f"{name}.atm").read_bytes())
        if kind == schema.MESH
    }
    assert orders == {schema.POSITIONS_RASTER, schema.POSITIONS_HILBERT}


def test_walls_survive_in_the_conformance_file():
    m = codec.decode_mesh((VECTORS / "gray8_steps.atm").read_bytes())
    assert len(m.constraints) == 2
    for line in m.constraints:
        assert set(m.vertices[line, 0]) in ({23}, {24})


def test_decoding_rule_by_hand():
    """Spec §5 on one pixel: the centre of a triangle's edge rounds half up."""
    from codec.mesh import Mesh

    vertices = np.array([[0, 0], [2, 0], [0, 2], [2, 2]])
    triangles = np.array([[0, 1, 3], [0, 3, 2]])
    m = Mesh(vertices, np.array([0, 1, 2, 4], np.uint8), triangles, 3, 3)
    out = render(m)
    # (1, 0) halfway between values 0 and 1 -> 0.5 rounds up to 1
    assert out[0, 1] == 1
    # (1, 1) on the diagonal, halfway between 0 and 4 -> 2
    assert out[1, 1] == 2
    # (2, 1) halfway between 1 and 4 -> 2.5 -> 3
    assert out[1, 2] == 3

"""The MESH payload's number transforms against the rules of ATM.md §4.2, written out
as plain loops: the Hilbert curve, the turned polyline steps, and the samples'
parents and their sums."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codec import meshcode
from codec.coding import hilbert_keys, hilbert_levels, hilbert_points
from codec.triangulate import triangulate


def spec_hilbert(x: int, y: int, n: int) -> int:
    d, s = 0, n // 2
    while s > 0:
        rx, ry = int(x & s != 0), int(y & s != 0)
        d += s * s * ((3 * rx) ^ ry)
        if ry == 0:
            if rx == 1:
                x, y = n - 1 - x, n - 1 - y
            x, y = y, x
        s //= 2
    return d


@given(st.integers(0, 13), st.data())
def test_hilbert_keys_follow_the_spec_and_invert(levels, data):
    n = 1 << levels
    pts = data.draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), min_size=1, max_size=40))
    x, y = np.array(pts).T
    d = hilbert_keys(x, y, levels)
    assert d.tolist() == [spec_hilbert(int(a), int(b), n) for a, b in pts]
    bx, by = hilbert_points(d, levels)
    assert bx.tolist() == x.tolist() and by.tolist() == y.tolist()


def test_every_hilbert_key_is_one_pixel():
    for levels in range(0, 7):
        d = np.arange(1 << 2 * levels)
        x, y = hilbert_points(d, levels)
        assert len(set(zip(x.tolist(), y.tolist()))) == len(d)
        # consecutive keys are neighbouring pixels: it is a curve
        assert (np.abs(np.diff(x)) + np.abs(np.diff(y)) == 1).all()


def test_hilbert_levels_cover_the_band():
    assert [hilbert_levels(w, h) for w, h in [(1, 1), (2, 1), (3, 2), (4, 4), (5, 3), (640, 480)]] == [0, 1, 2, 2, 3, 10]


def spec_quadrant(a: int, b: int) -> int:
    if a > 0 and b >= 0:
        return 0
    if a <= 0 and b > 0:
        return 1
    if a < 0 and b <= 0:
        return 2
    return 3


def spec_turn(a: int, b: int, quarters: int) -> tuple[int, int]:
    for _ in range(quarters % 4):
        a, b = -b, a
    return a, b


steps = st.tuples(st.integers(-9, 9), st.integers(-9, 9)).filter(lambda s: s != (0, 0))


@given(st.lists(st.lists(steps, min_size=1, max_size=12), min_size=1, max_size=6))
def test_turned_steps_follow_the_spec_and_invert(polylines):
    flat = np.array([s for line in polylines for s in line])
    lengths = np.array([len(line) + 1 for line in polylines])
    stored = meshcode.turned_steps(flat, lengths)
    expected = []
    for line in polylines:
        prev = None
        for a, b in line:
            expected.append((a, b) if prev is None else spec_turn(a, b, 4 - spec_quadrant(*prev)))
            prev = (a, b)
    assert stored.tolist() == [list(e) for e in expected]
    assert meshcode.unturned_steps(stored, lengths).tolist() == flat.tolist()


def test_a_straight_wall_stores_one_step_whatever_its_direction():
    for step in [(3, 1), (-1, 3), (-3, -1), (1, -3)]:
        stored = meshcode.turned_steps(np.array([step] * 5), np.array([6]))
        assert {tuple(s) for s in stored[1:].tolist()} == {(3, 1)}


@settings(max_examples=40)
@given(st.integers(3, 60), st.integers(0, 2**32 - 1))
def test_sample_parents_and_sums_follow_the_spec(count, seed):
    rng = np.random.default_rng(seed)
    keys = rng.choice(24 * 18, size=count, replace=False)
    vertices = np.stack([keys % 24, keys // 24], 1)
    vertices = np.unique(np.r_[vertices, [[0, 0], [23, 0], [0, 17], [23, 17]]], axis=0)
    triangles = triangulate(vertices)
    order = rng.permutation(len(vertices))
    parent = meshcode.sample_parents(triangles, order)
    place = {int(v): j for j, v in enumerate(order)}
    for j, v in enumerate(order.tolist()):
        earlier = [place[int(u)] for t in triangles.tolist() if v in t for u in t if place[int(u)] < j]
        assert parent[j] == (max(earlier) if earlier else j - 1)
    increments = rng.integers(-50, 50, (len(order), 2))
    sums = meshcode.tree_sums(increments, parent)
    expected = np.zeros_like(increments)
    for j in range(len(order)):
        expected[j] = increments[j] + (expected[parent[j]] if parent[j] >= 0 else 0)
    np.testing.assert_array_equal(sums, expected)


def test_decoded_polylines_read_as_a_list_of_index_arrays() -> None:
    """A decoded band's constraints (mesh.Polylines: one flat array and the lengths)
    behave as the list of index arrays a mesher makes: length, indexing from either
    end, slices, iteration, concatenation and pickling."""
    import pickle

    from codec.mesh import Polylines

    flat = np.arange(10, 19, dtype=np.int64)
    lines = Polylines(flat, np.array([2, 4, 3], np.int64))
    expected = [[10, 11], [12, 13, 14, 15], [16, 17, 18]]
    assert len(lines) == 3 and bool(lines) and not Polylines(flat[:0], flat[:0])
    assert [c.tolist() for c in lines] == expected
    assert lines[-1].tolist() == expected[-1] and lines[1].tolist() == expected[1]
    assert [c.tolist() for c in lines[1:]] == expected[1:]
    assert np.concatenate(lines).tolist() == flat.tolist()
    with pytest.raises(IndexError):
        lines[3]
    assert [c.tolist() for c in pickle.loads(pickle.dumps(lines))] == expected


def _quantised_in_python(values: np.ndarray, steps: np.ndarray, parents: np.ndarray, top: int) -> np.ndarray:
    """meshcode.quantise's loop as it was in Python (Python integers: floor division)."""
    out = np.empty_like(values)
    for c in range(values.shape[1]):
        rebuilt = [0]
        for v, s, p in zip(values[:, c].tolist(), steps.tolist(), parents.tolist()):
            prev = rebuilt[p + 1]
            prev += ((2 * (v - prev) + s) // (2 * s)) * s
            if prev > top:
                prev -= -(-(prev - top) // s) * s
            elif prev < 0:
                prev -= (prev // s) * s
            rebuilt.append(prev)
        out[:, c] = rebuilt[1:]
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 300), st.integers(1, 3), st.sampled_from([255, 65535]))
def test_the_samples_kernel_quantises_as_the_python_loop_did(seed: int, n: int, channels: int, top: int) -> None:
    """#20: codec._samples.quantised replaced a Python loop over the vertices (1-1.5 ms
    of a 512² encode); the same numbers, also where rounding runs past 0 or top, with
    steps of 1 and steps larger than the range."""
    from codec.native import _samples

    rng = np.random.default_rng(seed)
    values = rng.integers(-3, top + 4, (n, channels)).astype(np.int64)
    steps = rng.choice([1, 2, 3, 7, 40, 2 * top + 1], n).astype(np.int64)
    parents = np.array([rng.integers(-1, i) if i else -1 for i in range(n)], np.int64)
    got = _samples.quantised(values, steps, parents, top)
    assert np.array_equal(got, _quantised_in_python(values, steps, parents, top))


def test_the_samples_kernel_refuses_what_it_cannot_follow() -> None:
    from codec.native import _samples

    values = np.zeros((3, 1), np.int64)
    with pytest.raises(ValueError, match="earlier sample"):
        _samples.quantised(values, np.ones(3, np.int64), np.array([-1, 1, 0]), 255)
    with pytest.raises(ValueError, match="earlier sample"):
        _samples.quantised(values, np.ones(3, np.int64), np.array([-2, 0, 0]), 255)
    with pytest.raises(ValueError, match="below 1"):
        _samples.quantised(values, np.array([1, 0, 1]), np.array([-1, 0, 0]), 255)
    with pytest.raises(ValueError, match="a step and a parent"):
        _samples.quantised(values, np.ones(2, np.int64), np.array([-1, 0, 0]), 255)


def test_the_varint_byte_histograms_are_those_of_the_written_varints() -> None:
    """codec._samples.varint_histograms counts, for every shift, the bytes that
    coding.varints writes for the shifted values (position_fields' size estimates),
    one- to six-byte varints included; it refuses negative values and shifts."""
    from codec.coding import varints
    from codec.native import _samples

    rng = np.random.default_rng(8)
    values = np.concatenate([rng.integers(0, 300, 500), rng.integers(0, 1 << 40, 50), [0, 127, 128, 16383, 16384]])
    counts = _samples.varint_histograms(values.astype(np.int64), 2, 9)
    for row, k in zip(counts, range(2, 10)):
        data = np.frombuffer(varints(values >> k), np.uint8)
        assert np.array_equal(row, np.bincount(data, minlength=256))
    with pytest.raises(ValueError, match="negative"):
        _samples.varint_histograms(np.array([3, -1], np.int64), 0, 1)
    with pytest.raises(ValueError, match="shifts"):
        _samples.varint_histograms(np.array([3], np.int64), 2, 1)

"""The compiled MESH field kernels (codec/_fields.pyx) against the definitions they
replace: LEB128 varints, the sample tree's running sums, and their refusals of
malformed input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codec import coding, meshcode
from codec.errors import CorruptError


@settings(max_examples=80)
@given(st.lists(st.integers(0, 2**35 - 1), max_size=200))
def test_varints_round_trip(values: list[int]) -> None:
    data = coding.varints(np.array(values, dtype=np.uint64))
    assert coding.unvarints(data, len(values), "test").tolist() == values


@pytest.mark.parametrize("data, count, message", [
    (b"\x01\x02", 3, "2 bytes do not hold 3 numbers"),
    (b"\x01\x82", 2, "do not hold"),                 # ends inside a number
    (b"\x81", 1, "do not hold"),
    (b"\x01", 0, "do not hold"),
    (b"\x80\x80\x80\x80\x80\x01", 1, "longer than 5 bytes"),
])
def test_malformed_varints_are_corrupt(data: bytes, count: int, message: str) -> None:
    with pytest.raises(CorruptError, match=message):
        coding.unvarints(data, count, "field")


def test_a_count_the_bytes_cannot_hold_allocates_nothing() -> None:
    """A file that declares 10**12 numbers in one byte is refused by the count check,
    before an array of that count (8 TB) is asked for."""
    with pytest.raises(CorruptError, match="1 bytes do not hold 1000000000000 numbers"):
        coding.unvarints(b"\x01", 10**12, "field")


def test_tree_sums_follow_deep_chains_and_wrap_like_int64() -> None:
    """A chain as deep as the sequence (each sample's parent the one before) and a
    sum past int64 that wraps as numpy's arithmetic does (the caller's range check
    then refuses it)."""
    n = 5000
    increments = np.arange(n, dtype=np.int64).reshape(n, 1)
    parent = np.arange(-1, n - 1)
    assert np.array_equal(meshcode.tree_sums(increments, parent)[:, 0], np.cumsum(np.arange(n)))
    big = np.array([[2**62], [2**62]], np.int64)
    wrapped = meshcode.tree_sums(big, np.array([-1, 0]))
    assert wrapped[1, 0] == -(2**63)
    one = meshcode.tree_sums(np.array([3, 4, 5]), np.array([-1, 0, 0]))
    assert one.tolist() == [3, 7, 8]


def test_tree_sums_of_no_samples() -> None:
    """A band without vertices has no samples: empty sums of the increments' shape,
    not an error from reshaping nothing."""
    for shape in [(0,), (0, 1), (0, 3)]:
        sums = meshcode.tree_sums(np.zeros(shape, np.int64), np.zeros(0, np.int64))
        assert sums.shape == shape


def test_malformed_trees_are_corrupt() -> None:
    with pytest.raises(CorruptError, match="does not come before"):
        meshcode.tree_sums(np.zeros((3, 1), np.int64), np.array([-1, 2, 0]))
    triangles = np.array([[0, 1, 2]])
    with pytest.raises(CorruptError, match="no permutation"):
        meshcode.sample_parents(triangles, np.array([0, 0, 1]))
    with pytest.raises(CorruptError, match="beyond"):
        meshcode.sample_parents(np.array([[0, 1, 7]]), np.array([0, 1, 2]))
    vertices = np.array([[0, 0], [1, 0], [0, 1]])
    with pytest.raises(CorruptError, match="beyond"):
        meshcode.vertex_steps(vertices, np.array([[0, 1, 5]]), 4, False, areas=np.array([1]))


def test_a_package_without_its_kernels_says_how_to_build_them(monkeypatch) -> None:
    """No fallback: an install that skipped the build fails at import, saying what to
    run (None in sys.modules, and no attribute on the package, make that import fail
    as a missing file would)."""
    import importlib
    import sys

    import codec

    monkeypatch.setitem(sys.modules, "codec._fields", None)
    monkeypatch.delattr(codec, "_fields")
    monkeypatch.delitem(sys.modules, "codec.native")
    with pytest.raises(ImportError, match=r"not built: install the package with `pip install -e \.`"):
        importlib.import_module("codec.native")


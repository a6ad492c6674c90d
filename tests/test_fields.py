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



# The kernels below replace numpy passes whose per-call cost dominated decoding files
# of many tiny bands; each is checked against the definition it replaces.

def _reference():
    from codec.format_spec import reference_decoder

    return reference_decoder


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 16), st.integers(0, 2**32 - 1))
def test_hilbert_kernels_follow_the_spec(levels: int, seed: int) -> None:
    ref = _reference()
    rng = np.random.default_rng(seed)
    x, y = rng.integers(0, 1 << levels, (2, 50))
    d = coding.hilbert_keys(x, y, levels)
    assert d.tolist() == [ref.hilbert_distance(1 << levels, int(a), int(b)) for a, b in zip(x, y)]
    back = coding.hilbert_points(d, levels)
    assert back[0].tolist() == x.tolist() and back[1].tolist() == y.tolist()
    # shapes are kept, and nothing at all is no error
    assert coding.hilbert_keys(x.reshape(5, 10), y.reshape(5, 10), levels).shape == (5, 10)
    assert coding.hilbert_keys(x[:0], y[:0], levels).shape == (0,)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_canonical_triangles_rotate_then_sort(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 10 ** int(rng.integers(1, 8))))
    t = np.array([rng.choice(n, 3, replace=False) for _ in range(int(rng.integers(0, 60)))], np.int64).reshape(-1, 3)
    if len(t) > 2:
        t[-1] = t[0][[1, 2, 0]]  # a row repeated in another rotation
    rotations = [min(tuple(r[i:]) + tuple(r[:i]) for i in range(3)) for r in t.tolist()]
    assert coding.canonical_triangles(t).tolist() == sorted(map(list, rotations))


def _band(seed: int, width: int = 40, rows: int = 12):
    """Random distinct vertices in raster order with the band's corners, and their
    Delaunay triangles."""
    from codec.triangulate import triangulate

    rng = np.random.default_rng(seed)
    keys = rng.choice(width * rows, int(rng.integers(4, 60)), replace=False)
    keys = np.unique(np.r_[keys, 0, width - 1, (rows - 1) * width, rows * width - 1])
    vertices = np.stack([keys % width, keys // width], 1).astype(np.int64)
    return vertices, coding.canonical_triangles(triangulate(vertices))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 300), st.booleans())
def test_vertex_steps_follow_the_spec(seed: int, step: int, pinned: bool) -> None:
    ref = _reference()
    vertices, triangles = _band(seed)
    band = ref.Band(1 if pinned else 0, 12)
    band.xs, band.ys = vertices[:, 0].tolist(), vertices[:, 1].tolist()
    band.triangles = [tuple(t) for t in triangles.tolist()]
    assert meshcode.vertex_steps(vertices, triangles, step, pinned).tolist() == ref.vertex_steps(band, step)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.booleans(), st.sampled_from([1, 3]))
def test_band_values_is_steps_parents_and_sums(seed: int, step: int, pinned: bool, channels: int) -> None:
    """The decoder's one-pass sample stage equals vertex_steps, sample_parents and
    tree_sums composed, as the encoder defines them."""
    from codec.native import _fields

    vertices, triangles = _band(seed)
    n = len(vertices)
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    parent = meshcode.sample_parents(triangles, order)
    steps = meshcode.vertex_steps(vertices, triangles, step, pinned)[order][:, None]
    # a large root and residuals of either sign that cannot take a sum below 0
    residuals = rng.integers(-3, 100, (n, channels))
    residuals[0] = 10**6
    expected = meshcode.tree_sums(residuals * steps, parent)
    samples = np.frombuffer(coding.varints(coding.zigzag(residuals).ravel()), np.uint8)
    w, h = int(vertices[:, 0].max()) + 1, int(vertices[:, 1].max()) + 1
    status, out, areas, checks = _fields.band_values(vertices, triangles, samples, channels, order, step,
                                                     meshcode.STEP_RANGE, pinned, 2**40, 9, w, h)
    assert status == _fields.Values.VALUES_OK
    assert out.dtype == np.int64 and out.shape == ((n,) if channels == 1 else (n, channels))
    assert np.array_equal(out.reshape(n, channels)[order], expected)
    assert np.array_equal(areas, meshcode.doubled_areas(vertices, triangles))
    assert checks == _fields.mesh_checks(vertices, triangles, None, w, h)
    for top, dtype in ((255, np.uint8), (65535, np.uint16)):
        small = np.minimum(residuals, 0) if top == 255 else residuals
        small[0] = 0
        stored = np.frombuffer(coding.varints(coding.zigzag(small).ravel()), np.uint8)
        status, out, _, _ = _fields.band_values(vertices, triangles, stored, channels, order, 1,
                                                meshcode.STEP_RANGE, False, top, 5, w, h)
        sums = meshcode.tree_sums(small, meshcode.sample_parents(triangles, order))
        if (sums < 0).any() or (sums > top).any():
            assert status == _fields.Values.VALUES_SAMPLE
        else:
            assert status == _fields.Values.VALUES_OK and out.dtype == dtype
            assert np.array_equal(out.reshape(n, channels)[order], sums)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 3))
def test_band_values_checks_are_mesh_checks(seed: int, damage: int) -> None:
    """band_values' element checks, made in its pass over the triangles, are
    mesh_checks' on the same vertices and triangles, bad ones too (a vertex outside,
    out of raster order, a triangle turned over)."""
    from codec.native import _fields

    vertices, triangles = _band(seed)
    vertices, triangles = vertices.copy(), triangles.copy()
    rng = np.random.default_rng(seed)
    w, h = int(vertices[:, 0].max()) + 1, int(vertices[:, 1].max()) + 1
    if damage == 1:
        triangles[rng.integers(len(triangles))] = triangles[rng.integers(len(triangles))][[0, 2, 1]]
    elif damage == 2:
        vertices[rng.integers(len(vertices)), 1] = h
    elif damage == 3:
        i = rng.integers(len(vertices) - 1)
        vertices[[i, i + 1]] = vertices[[i + 1, i]]
    n = len(vertices)
    samples = np.zeros(n, np.uint8)
    status, _, areas, checks = _fields.band_values(vertices, triangles, samples, 1, np.arange(n), 1,
                                                   meshcode.STEP_RANGE, False, 255, 5, w, h)
    assert status == _fields.Values.VALUES_OK
    assert checks == _fields.mesh_checks(vertices, triangles, None, w, h)
    assert checks == _fields.mesh_checks(vertices, triangles, areas, w, h)


def test_band_values_refusals() -> None:
    from codec.native import _fields

    vertices, triangles = _band(7)
    n = len(vertices)
    order = np.arange(n)
    zero = np.zeros(n, np.int64)

    def status(tri=triangles, zig=zero, seq=order, top=255, raw=None):
        data = np.frombuffer(coding.varints(zig), np.uint8) if raw is None else np.frombuffer(raw, np.uint8)
        return _fields.band_values(vertices, tri, data, 1, seq, 1, meshcode.STEP_RANGE, False, top, 5, 100, 100)[0]

    assert status() == _fields.Values.VALUES_OK
    bad = triangles.copy()
    bad[0, 2] = n
    assert status(tri=bad) == _fields.Values.VALUES_CORNER
    assert status(zig=np.r_[zero[:-1], 511]) == _fields.Values.VALUES_RESIDUAL
    assert status(seq=np.r_[order[:-1], 0]) == _fields.Values.VALUES_ORDER
    assert status(zig=np.r_[1, zero[1:]]) == _fields.Values.VALUES_SAMPLE  # -1 at the root
    # the varints' refusals first, as unvarints makes them: the count, then a number too long
    assert status(zig=zero[:-1]) == _fields.Values.VALUES_COUNT
    assert status(raw=bytes(n - 1) + b"\x80") == _fields.Values.VALUES_COUNT
    assert status(tri=bad, raw=bytes(n - 1) + b"\x80\x80\x80\x80\x80\x00") == _fields.Values.VALUES_LONG
    assert status(raw=bytes(n - 1) + b"\x80\x80\x80\x80\x00") == _fields.Values.VALUES_OK
    with pytest.raises(ValueError):
        status(seq=order[:-1])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5000), max_size=60), st.integers(0, 12))
def test_position_keys_follow_the_gaps(gaps: list[int], bits: int) -> None:
    """Keys from the stored gaps (the positions field's high parts and position_bits'
    low bits) as meshcode.position_fields splits them; refused as soon as a key
    leaves the span."""
    from codec.native import _fields

    fields = meshcode.position_fields(np.array(gaps, np.int64), bits)
    nums = coding.unvarints(fields["positions"], len(gaps) + 1, "test")
    packed = np.frombuffer(fields["position_bits"], np.uint8)
    keys = np.cumsum(np.array(gaps, np.int64) + 1) - 1
    span = int(keys[-1]) + 1 if gaps else 1
    ok, out = _fields.position_keys(nums[1:], packed, bits, span)
    assert ok and out.tolist() == keys.tolist()
    if gaps:
        assert _fields.position_keys(nums[1:], packed, bits, span - 1) == (False, None)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 300), st.integers(0, 32), st.integers(0, 9), st.integers(0, 2**32 - 1))
def test_position_keys_cut_every_field_width_at_every_bit(n: int, bits: int, extra: int, seed: int) -> None:
    """The low bits position_keys cuts from the field are numpy's unpacked bits, for
    every width up to 32 and every bit offset, whatever bytes follow the field (it may
    be given a longer buffer)."""
    from codec.native import _fields

    rng = np.random.default_rng(seed)
    low = rng.integers(0, 1 << bits, n, dtype=np.int64) if bits else np.zeros(n, np.int64)
    high = rng.integers(0, 4, n, dtype=np.int64)
    gaps = (high << bits) | low
    fields = meshcode.position_fields(gaps, bits)
    packed = np.frombuffer(fields["position_bits"] + rng.bytes(extra), np.uint8)
    # numpy's reading: each gap's bits, most significant first, one after another
    unpacked = np.unpackbits(packed)[: n * bits].reshape(n, bits).astype(np.int64)
    lows = (unpacked << np.arange(bits - 1, -1, -1)).sum(1) if bits else np.zeros(n, np.int64)
    keys = np.cumsum((high << bits) + lows + 1) - 1
    span = int(keys[-1]) + 1 if n else 1
    ok, out = _fields.position_keys(high, packed, bits, span)
    assert ok and out.tolist() == keys.tolist()


def test_validate_checks_elements_in_one_pass_whatever_the_arrays() -> None:
    """mesh.validate's element checks (a compiled pass) refuse each kind of bad mesh
    with its own message, for int32 and strided arrays as for int64."""
    from codec.mesh import Mesh, validate

    v = np.array([[0, 0], [3, 0], [0, 2], [3, 2]], np.int64)
    t = np.array([[0, 1, 3], [0, 3, 2]])
    t = np.array([r if meshcode.doubled_areas(v, r[None])[0] > 0 else r[[0, 2, 1]] for r in t])
    values = np.zeros(4, np.uint8)
    for cast in (lambda a: a, lambda a: a.astype(np.int32), lambda a: np.asfortranarray(a)):
        validate(Mesh(cast(v), values, cast(t), 4, 3))
        cases = {
            "outside the 4x3 image": (v + [0, 1], t),
            "share a pixel": (v[[0, 1, 2, 0]], t),
            "beyond the 4 stored": (v, np.where(t == 3, 4, t)),
            "degenerate or wrongly oriented": (v, t[:, [0, 2, 1]]),
            "exactly once": (v, t[:1]),
        }
        for message, (vv, tt) in cases.items():
            with pytest.raises(CorruptError, match=message):
                validate(Mesh(cast(vv), values, cast(tt), 4, 3))


def _fields_of_chains(width: int, rows: int, lines: list[np.ndarray]):
    """A parsed MeshPayload's polyline fields for polylines given as (x, y) points,
    coded as the encoder codes them (start gaps, turned steps, zigzag varints)."""
    from types import SimpleNamespace

    lengths = np.array([len(p) for p in lines], np.int64)
    flat = np.concatenate(lines) if lines else np.zeros((0, 2), np.int64)
    steps = meshcode.chain_steps(flat, lengths)
    keys = flat[:, 1] * width + flat[:, 0]
    start_keys = keys[np.cumsum(lengths) - lengths]
    return SimpleNamespace(
        polyline_count=len(lines), polyline_index_count=len(flat),
        polyline_lengths=coding.varints(lengths),
        polyline_starts=coding.varints(coding.zigzag(np.diff(start_keys, prepend=0))),
        polyline_steps=coding.varints(coding.zigzag(meshcode.turned_steps(steps[:, 1] - steps[:, 0], lengths)).ravel()),
    ), keys


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.integers(1, 30))
def test_chains_kernel_walks_the_turned_steps(seed: int, width: int, rows: int) -> None:
    """_fields.chains (through meshcode._polylines) gives the keys of the points the
    encoder coded: unturned_steps' turn and the walk from each start, in one pass."""
    rng = np.random.default_rng(seed)
    lines = []
    for _ in range(rng.integers(0, 6)):
        n = int(rng.integers(2, 9))
        pts = np.stack([rng.integers(0, width, n), rng.integers(0, rows, n)], 1)
        keep = np.r_[True, (np.diff(pts, axis=0) != 0).any(axis=1)]  # no empty step
        if keep.sum() >= 2:
            lines.append(pts[keep])
    m, keys = _fields_of_chains(width, rows, lines)
    lengths, line_keys, ranks, appear = meshcode._polylines(m, width, rows, "band")
    assert line_keys[ranks].tolist() == keys.tolist()
    assert line_keys.tolist() == sorted(set(keys.tolist()))
    assert line_keys[appear].tolist() == list(dict.fromkeys(keys.tolist()))  # first reached first


def test_chains_kernel_refuses_in_the_fields_order() -> None:
    """Each malformed polyline field gets its own message, and a band wrong in two
    ways gets the one of the field that comes first (starts before steps)."""
    line = [np.array([[1, 1], [4, 1], [4, 3]])]
    m, _ = _fields_of_chains(6, 5, line)
    cases = [
        (dict(polyline_index_count=4), "lengths do not add up"),
        (dict(polyline_starts=coding.varints(coding.zigzag(np.array([30])))), "starts outside the 6x5 band"),
        (dict(polyline_starts=coding.varints(coding.zigzag(np.array([30]))), polyline_steps=b"\x80"),
         "starts outside"),
        (dict(polyline_steps=b"\x80"), "polyline steps: 1 bytes do not hold 4 numbers"),
        (dict(polyline_steps=coding.varints(np.array([0, 0, 2, 2]))), "a polyline step is empty"),
        (dict(polyline_steps=coding.varints(coding.zigzag(np.array([6, 0, 1, 0])))), "longer than the band"),
        (dict(polyline_steps=coding.varints(coding.zigzag(np.array([5, 0, 1, 0])))), "leaves the 6x5 band"),
    ]
    for change, message in cases:
        bad = type(m)(**{**vars(m), **change})
        with pytest.raises(CorruptError, match=message):
            meshcode._polylines(bad, 6, 5, "band")


def test_band_vertices_merges_the_key_lists() -> None:
    """_fields.line_ranks and band_vertices: the vertices of both increasing key
    lists in raster order, across many rows (a row walk stands in for a division per
    key), each polyline point's vertex, the walls, and the polyline vertices in the
    order the chains first reach them."""
    from codec.native import _fields

    rng = np.random.default_rng(5)
    width = 37
    keys = np.unique(rng.integers(0, width * 300, 2000))
    on_line = rng.random(len(keys)) < 0.3
    line_keys, free_keys = keys[on_line], keys[~on_line]
    chain = rng.permutation(np.r_[line_keys, line_keys[:50]])
    lengths = np.array([len(chain) - 2, 2])
    distinct, ranks, appear = _fields.line_ranks(chain, np.argsort(chain))
    assert distinct.tolist() == line_keys.tolist()
    ok, vertices, places, flat, walls, first = _fields.band_vertices(distinct, free_keys, ranks, appear, lengths, width)
    assert ok
    assert vertices.tolist() == np.stack([keys % width, keys // width], 1).tolist()
    assert keys[places].tolist() == free_keys.tolist()
    assert keys[flat].tolist() == chain.tolist()
    assert keys[first].tolist() == list(dict.fromkeys(chain.tolist()))
    assert walls.tolist() == [[flat[i], flat[i + 1]] for i in range(len(chain) - 3)] + [[flat[-2], flat[-1]]]
    shared = np.r_[free_keys, line_keys[:1]]
    shared.sort()
    assert not _fields.band_vertices(distinct, shared, ranks, appear, lengths, width)[0]
    assert _fields.line_ranks(chain, np.zeros(len(chain), np.int64)) is None  # no permutation


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 50), st.integers(0, 400), st.floats(0, 1),
       st.sampled_from(["none", "first", "last", "any"]))
def test_band_vertices_merge_is_the_sorted_union(seed: int, width: int, n: int, share: float, dup: str) -> None:
    """The merge puts every key of both increasing lists in its sorted
    place, whatever the mix (either list empty, one list's keys all before the
    other's), and refuses a key in both lists wherever it lies."""
    from codec.native import _fields

    rng = np.random.default_rng(seed)
    keys = np.unique(rng.integers(0, width * 60, n))
    if rng.random() < 0.2:  # one list's keys all before the other's
        on_line = np.arange(len(keys)) < int(share * len(keys))
    else:
        on_line = rng.random(len(keys)) < share
    line_keys, free_keys = keys[on_line], keys[~on_line]
    lengths = np.array([len(line_keys)]) if len(line_keys) >= 2 else np.zeros(0, np.int64)
    chain = line_keys if len(lengths) else np.zeros(0, np.int64)
    distinct, ranks, appear = _fields.line_ranks(chain, np.argsort(chain, kind="stable"))
    if len(lengths) == 0:
        line_keys = free_keys[:0]
        free_keys = keys
    ok, vertices, places, flat, walls, first = _fields.band_vertices(distinct, free_keys, ranks, appear, lengths, width)
    assert ok
    merged = np.sort(np.r_[line_keys, free_keys])
    assert vertices.tolist() == np.stack([merged % width, merged // width], 1).tolist()
    assert merged[places].tolist() == free_keys.tolist()
    assert merged[flat].tolist() == chain.tolist()
    if dup != "none" and len(distinct) and len(free_keys):
        at = {"first": 0, "last": len(distinct) - 1, "any": int(rng.integers(0, len(distinct)))}[dup]
        shared = np.unique(np.r_[free_keys, distinct[at]])
        assert not _fields.band_vertices(distinct, shared, ranks, appear, lengths, width)[0]


def test_band_vertices_takes_the_largest_keys() -> None:
    """Keys up to int64's largest are merged in their places: the lists' ends go by
    their counts, not by a sentinel key past them."""
    from codec.native import _fields

    top, wide = 2**63 - 1, 2**62
    line = np.array([5, top], np.int64)
    ranks, appear = np.array([0, 1], np.int64), np.array([0, 1], np.int64)
    ok, vertices, places, flat, _, _ = _fields.band_vertices(line, np.array([0, 7], np.int64), ranks, appear,
                                                             np.array([2]), wide)
    assert ok and vertices.tolist() == [[0, 0], [5, 0], [7, 0], [top - wide, 1]]
    assert places.tolist() == [0, 2] and flat.tolist() == [1, 3]
    assert not _fields.band_vertices(line, np.array([0, top], np.int64), ranks, appear, np.array([2]), wide)[0]
    ok, vertices, places, _, _, _ = _fields.band_vertices(line[:0], np.array([3, top], np.int64), ranks[:0],
                                                          appear[:0], np.zeros(0, np.int64), wide)
    assert ok and vertices.tolist() == [[3, 0], [top - wide, 1]] and places.tolist() == [0, 1]


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["fans", "hub", "far", "negative"]))
def test_canonical_triangles_counting_sort_and_its_fallback(seed: int, kind: str) -> None:
    """The counting sort (fans of a mesh's indices; a hub vertex starting over 32
    rows is sorted by qsort) and the qsort of rows whose indices are far beyond
    their count or negative give the same order: each row's smallest rotation, the
    rows sorted."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 400))
    n = {"fans": 60, "hub": 60, "far": 1 << 40, "negative": 60}[kind]
    t = rng.integers(0, n, (m, 3)).astype(np.int64)
    if kind == "hub":
        t[: m // 2, 0] = 0
    if kind == "negative":
        t[0, 1] = -3
    rotations = [min(tuple(r[i:]) + tuple(r[:i]) for i in range(3)) for r in t.tolist()]
    assert coding.canonical_triangles(t).tolist() == sorted(map(list, rotations))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 62), st.integers(0, 3000), st.integers(0, 2**32 - 1))
def test_argsort_keys_sorts_distinct_keys_as_numpy(bits: int, n: int, seed: int) -> None:
    """The radix sort of the decoder's Hilbert order gives numpy's argsort of distinct
    keys below the span, in every digit layout (spans of 1 to 2**62: no pass to four),
    and refuses a key outside the span."""
    from codec.native import _fields

    span = 1 << bits
    rng = np.random.default_rng(seed)
    keys = np.unique(rng.integers(0, span, min(n, span), dtype=np.int64))
    rng.shuffle(keys)
    assert np.array_equal(_fields.argsort_keys(keys, span), np.argsort(keys))
    if len(keys):
        for bad in (span, -1):
            wrong = keys.copy()
            wrong[-1] = bad
            assert _fields.argsort_keys(wrong, span) is None


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 40), st.integers(0, 3000), st.integers(0, 2**32 - 1))
def test_argsort_keys_is_a_stable_argsort(bits: int, n: int, seed: int) -> None:
    """With keys repeated (polyline points on shared pixels), the radix sort is numpy's
    stable argsort, which line_ranks takes for one."""
    from codec.native import _fields

    span = 1 << bits
    rng = np.random.default_rng(seed)
    keys = rng.integers(0, min(span, max(1, n // 3)), n, dtype=np.int64)
    assert np.array_equal(_fields.argsort_keys(keys, span), np.argsort(keys, kind="stable"))


@pytest.mark.parametrize("dtype", [np.uint8, np.int8, np.uint16, np.int16, np.int32, np.float32])
@pytest.mark.parametrize("channels", [1, 3])
def test_fill_holes_is_numpys_masked_assignment(dtype, channels: int) -> None:
    """stream._fill (the fill_holes kernel) sets every channel of the hole pixels to the
    value, bit for bit (a NaN too), and leaves the others, as rows[holes] = value."""
    from codec import stream

    rng = np.random.default_rng(channels)
    shape = (37, 23) + ((channels,) if channels > 1 else ())
    rows = rng.integers(0, 100, shape).astype(dtype)
    holes = rng.random((37, 23)) < 0.4
    for value in ([0, -5, 7] if np.dtype(dtype).kind != "u" else [0, 7]) + ([np.nan] if dtype == np.float32 else []):
        expected = rows.copy()
        expected[holes] = value
        got = rows.copy()
        bits = np.dtype(f"u{np.dtype(dtype).itemsize}")
        stream._fill(got, holes, int(np.array(value, dtype).view(bits)))
        assert np.array_equal(got.view(bits), expected.view(bits))
    strided = rows.copy()[::2]  # not a decoder's own rows: numpy's assignment
    expected = strided.copy()
    expected[holes[::2]] = 3
    stream._fill(strided, holes[::2], int(np.array(3, dtype).view(bits)))
    assert np.array_equal(strided, expected)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 300), st.integers(1, 300))
def test_curve_order_is_hilbert_keys_then_their_sort(seed: int, width: int, rows: int) -> None:
    """_fields.curve_order (the sample order of free vertices stored in raster order)
    is the Hilbert keys of the vertices at the places, stably sorted; a place that is
    no vertex is refused."""
    from codec.native import _fields

    rng = np.random.default_rng(seed)
    keys = np.unique(rng.integers(0, width * rows, int(rng.integers(1, 400))))
    vertices = np.stack([keys % width, keys // width], 1).astype(np.int64)
    places = np.sort(rng.choice(len(vertices), int(rng.integers(0, len(vertices) + 1)), replace=False)).astype(np.int64)
    levels = coding.hilbert_levels(width, rows)
    curve = coding.hilbert_keys(vertices[places, 0], vertices[places, 1], levels)
    expected = places[np.argsort(curve, kind="stable")]
    assert np.array_equal(_fields.curve_order(vertices, places, *coding.hilbert_tables(levels), 1 << 2 * levels),
                          expected)
    if len(places):
        wrong = places.copy()
        wrong[-1] = len(vertices)
        assert _fields.curve_order(vertices, wrong, *coding.hilbert_tables(levels), 1 << 2 * levels) is None


def _band_payloads(hilbert: bool) -> list:
    """Parsed MESH payloads of small encodes (gray, banded, with walls), their free
    vertices stored in raster order or (hilbert: the trial sizes rigged) along the
    curve."""
    import io

    import codec
    from codec import container, frames
    from tests.corpus import load_corpus

    image = load_corpus()["camera"][:120:, :150]
    real = frames.trial_size
    calls = [0]

    def curve_wins(data: bytes) -> float:  # encode_band asks raster first, then the curve
        calls[0] += 1
        return 1e12 if calls[0] % 2 else 0.0

    if hilbert:
        meshcode.frames.trial_size = curve_wins
    try:
        files = [codec.encode(image, points=p, band_height=b) for p in (40, 600) for b in (None, 16)]
    finally:
        meshcode.frames.trial_size = real
    payloads = []
    for data in files:
        reader = container.Reader(io.BytesIO(data))
        y0 = 0
        while True:
            ctype, payload, offset = reader._next_chunk()
            if ctype == container.schema.END:
                break
            if ctype == container.schema.MESH:
                _, raw = reader._check_frame(payload, "MESH", y0)
                fields = container._MeshFields(raw, "MESH")
                payloads.append((raw, reader.header.width))
                y0 = fields.y0 + fields.rows - 1
    assert all(container._MeshFields(raw, "x").position_order == int(hilbert) for raw, _ in payloads)
    return payloads


def _band_front(m, width: int):
    rows = int(m.rows)
    levels = coding.hilbert_levels(width, rows)
    return meshcode._fields.band_front(
        m.polyline_lengths, m.polyline_starts, m.polyline_steps, int(m.polyline_count), int(m.polyline_index_count),
        m.positions, m.position_bits, int(m.vertex_count), width, rows, m.position_order == 0,
        coding.MAX_VARINT_BYTES, meshcode.MAX_POSITION_BITS, *coding.hilbert_tables(levels),
        *coding.hilbert_inverse_tables(), 1 << 2 * levels)


@pytest.mark.parametrize("hilbert", [False, True])
def test_band_front_is_the_separate_passes(hilbert: bool) -> None:
    """_fields.band_front (one call) gives what meshcode._front's separate passes give
    (polylines, positions, merge, sample order), on every band it accepts; on damaged
    fields (bits flipped, bytes dropped or added, counts off by one) it accepts
    nothing the separate passes refuse, and decode_band then raises their message."""
    import random

    from codec import container

    rng = random.Random(7 + hilbert)
    names = ["polyline_lengths", "polyline_starts", "polyline_steps", "positions", "position_bits"]
    payloads = _band_payloads(hilbert)
    accepted = refused = 0
    for trial in range(1500):
        raw, width = rng.choice(payloads)
        m = container._MeshFields(raw, "x")
        if trial % 5:
            k = rng.randrange(len(names) + 1)
            if k < len(names):
                field = bytearray(bytes(getattr(m, names[k])))
                at = rng.randrange(len(field) + 1)
                if rng.random() < 0.5 and at < len(field):
                    field[at] ^= 1 << rng.randrange(8)
                elif rng.random() < 0.5 and at < len(field):
                    del field[at]
                else:
                    field.insert(at, rng.randrange(256))
                setattr(m, names[k], memoryview(bytes(field)))
            else:
                name = rng.choice(["polyline_count", "polyline_index_count", "vertex_count"])
                setattr(m, name, max(0, getattr(m, name) + rng.choice([-1, 1])))
        n, rows = int(m.vertex_count), int(m.rows)
        status, *fast = _band_front(m, width)
        try:
            slow = meshcode._front(m, n, width, rows, coding.hilbert_levels(width, rows), "x")
        except CorruptError:
            slow = None
        if status == meshcode._fields.Front.FRONT_OK:
            accepted += 1
            assert slow is not None, "band_front accepted fields the separate passes refuse"
            for a, b in zip(fast, slow):
                assert np.array_equal(np.asarray(a).reshape(-1), np.asarray(b).reshape(-1))
        else:
            refused += 1
            assert slow is None, "band_front refused fields the separate passes accept"
    assert accepted > 300 and refused > 300


def test_stack_bands_moves_and_renumbers_as_numpy() -> None:
    """_fields.stack_bands (stream.stack_bands' compiled pass) gives numpy's
    concatenation of each band's vertices moved down and triangles renumbered,
    empty bands included."""
    rng = np.random.default_rng(5)
    sizes = [(5, 4), (0, 0), (9, 11), (1, 0)]
    vs = [rng.integers(0, 50, (n, 2)).astype(np.int64) for n, _ in sizes]
    ts = [rng.integers(0, max(n, 1), (m, 3)).astype(np.int64) for n, m in sizes]
    down = np.array([0, 7, 7, 30], np.int64)
    vertices, triangles = meshcode._fields.stack_bands(vs, ts, down)
    offsets = np.cumsum([0] + [len(v) for v in vs[:-1]])
    assert np.array_equal(vertices, np.concatenate([v + [0, d] for v, d in zip(vs, down)]))
    assert np.array_equal(triangles, np.concatenate([t + o for t, o in zip(ts, offsets)]))
    with pytest.raises(ValueError):
        meshcode._fields.stack_bands(vs, ts[:-1], down)
    # arrays of the wrong width are refused, not read past their rows
    with pytest.raises(ValueError):
        meshcode._fields.stack_bands([np.arange(8).reshape(8, 1)], [np.arange(6).reshape(6, 1)], down[:1])
    with pytest.raises(ValueError):
        meshcode._fields.stack_bands([vs[0]], [np.zeros((4, 2), np.int64)], down[:1])


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.booleans(), st.sampled_from([1, 3]))
def test_band_values_without_areas_gives_the_same_samples_and_checks(seed: int, step: int, pinned: bool,
                                                                      channels: int) -> None:
    """want_areas=False (the decoder's call: mesh.validate takes the checks) leaves the
    areas out and changes nothing else: samples, checks and refusals as with them."""
    from codec.native import _fields

    vertices, triangles = _band(seed)
    n = len(vertices)
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    residuals = rng.integers(-3, 100, (n, channels))
    residuals[0] = 10**6
    samples = np.frombuffer(coding.varints(coding.zigzag(residuals).ravel()), np.uint8)
    w, h = int(vertices[:, 0].max()) + 1, int(vertices[:, 1].max()) + 1
    for top in (2**40, 255):  # accepted, and refused (VALUES_RESIDUAL / VALUES_SAMPLE)
        args = (vertices, triangles, samples, channels, order, step, meshcode.STEP_RANGE, pinned, top, 9, w, h)
        with_areas, without = _fields.band_values(*args), _fields.band_values(*args, False)
        assert without[2] is None and without[0] == with_areas[0] and without[3] == with_areas[3]
        assert (without[1] is None) == (with_areas[1] is None)
        if with_areas[1] is not None:
            assert np.array_equal(without[1], with_areas[1])

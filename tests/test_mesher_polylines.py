"""The polyline stage's compiled walks (codec._polylines) against the rules written out
plainly: chain order (section 3.3.2.1 of "Approximation of Digital Images with
Discontinuity-Preserving Adaptive Triangular Meshes": each chain from its first end in
scan-line order, a loop from its first pixel) and the paper's segment rule."""

from __future__ import annotations

import numpy as np
import pytest

from codec import native
from codec.mesher.polylines import _OFFSETS

OFFSETS = [tuple(int(v) for v in o) for o in _OFFSETS]


def _simple_mask(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A padded mask whose pixels have at most two 8-neighbours (a random mask without
    its bifurcations, as trace() cuts them)."""
    on = np.zeros((h + 2, w + 2), bool)
    on[1:-1, 1:-1] = rng.random((h, w)) < rng.uniform(0.1, 0.6)
    count = sum(np.roll(on, (-dy, -dx), axis=(0, 1)) for dy, dx in OFFSETS)
    return on & (count < 3)


def _chains_by_hand(mask: np.ndarray):
    """(flat order, chain, closed) walking the chains one by one in plain Python."""
    w = mask.shape[1]
    on = {(int(y), int(x)) for y, x in zip(*np.nonzero(mask))}
    nbrs = {p: [(p[0] + dy, p[1] + dx) for dy, dx in OFFSETS if (p[0] + dy, p[1] + dx) in on] for p in on}
    seen, chains = set(), []
    for p in sorted(on):
        if p in seen:
            continue
        comp, todo = {p}, [p]
        while todo:
            for q in nbrs[todo.pop()]:
                if q not in comp:
                    comp.add(q)
                    todo.append(q)
        seen |= comp
        ends = sorted(q for q in comp if len(nbrs[q]) <= 1)
        start, closed = (ends[0], False) if ends else (min(comp), True)
        cut = max(nbrs[start]) if closed else None
        walk, prev = [start], None
        while True:
            here = walk[-1]
            nxt = [q for q in nbrs[here] if q != prev and not (closed and {here, q} == {start, cut})]
            if not nxt or (closed and nxt[0] == start):
                break
            prev = here
            walk.append(nxt[0])
        chains.append((start, walk, closed))
    chains.sort()
    flat = [y * w + x for _, walk, _ in chains for y, x in walk]
    chain = [c for c, (_, walk, _) in enumerate(chains) for _ in walk]
    return np.array(flat, np.int64), np.array(chain, np.int64), np.array([c for *_, c in chains], bool)


def _control_points_by_hand(xy: np.ndarray, first: int, last: int, k: int, d: float) -> list[int]:
    out, a = [first], first
    if last == first:
        return out
    c = min(a + k, last)
    while True:
        ax, ay = xy[a]
        sx, sy = xy[c] - xy[a]
        bad = None
        for i in range(a + 1, c):
            rx, ry = xy[i, 0] - ax, xy[i, 1] - ay
            t = min(max((rx * sx + ry * sy) / max(sx * sx + sy * sy, 1e-12), 0.0), 1.0)
            if (rx - t * sx) ** 2 + (ry - t * sy) ** 2 > d * d:
                bad = i
                break
        if bad is not None:
            out.append(bad)
            a, c = bad, min(bad + k, last)
        elif c == last:
            return out + [last]
        else:
            c = min(c + k, last)


@pytest.mark.parametrize("seed", range(30))
def test_chains_are_walked_from_their_first_end(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mask = _simple_mask(rng, *rng.integers(1, 30, 2))
    offsets = np.array([dy * mask.shape[1] + dx for dy, dx in OFFSETS], np.int64)
    got = native._polylines.order_chains(mask.ravel().view(np.uint8), offsets)
    for a, b in zip(got, _chains_by_hand(mask)):
        assert np.array_equal(a, b)


def test_a_loop_starts_at_its_first_pixel_towards_its_earlier_neighbour() -> None:
    mask = np.zeros((6, 7), bool)
    ring = [(1, 2), (1, 3), (2, 4), (3, 4), (4, 3), (4, 2), (3, 1), (2, 1)]
    for y, x in ring:
        mask[y, x] = True
    offsets = np.array([dy * 7 + dx for dy, dx in OFFSETS], np.int64)
    flat, chain, closed = native._polylines.order_chains(mask.ravel().view(np.uint8), offsets)
    assert closed.tolist() == [True] and chain.tolist() == [0] * 8
    # from (1, 2): its neighbours are (1, 3) (flat 10) and (2, 1) (flat 15); the walk
    # leaves towards the earlier one and ends at the later one
    assert [divmod(int(p), 7) for p in flat] == ring


@pytest.mark.parametrize("seed", range(30))
def test_control_points_follow_the_segment_rule(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    sizes = rng.integers(1, 40, rng.integers(1, 6))
    # random walks: each chain a run of neighbouring pixels
    steps = rng.integers(-1, 2, (int(sizes.sum()), 2))
    xy = np.cumsum(steps, axis=0).astype(np.float64)
    last = np.cumsum(sizes) - 1
    first = last - sizes + 1
    for k, d in ((4, 1.0), (1, 0.0), (3, 0.5), (6, 2.0)):
        want = [i for f, l in zip(first, last) for i in _control_points_by_hand(xy, int(f), int(l), k, d)]
        got = native._polylines.control_points(xy, first.astype(np.int64), last.astype(np.int64), k, d)
        assert got.tolist() == want


def test_the_kernels_refuse_what_they_cannot_walk() -> None:
    mask = np.zeros((5, 5), bool)
    mask[2, 1:4] = mask[1, 2] = True  # (2, 2) has three neighbours
    offsets = np.array([dy * 5 + dx for dy, dx in OFFSETS], np.int64)
    with pytest.raises(ValueError, match="more than two"):
        native._polylines.order_chains(mask.ravel().view(np.uint8), offsets)
    edge = np.zeros((5, 5), bool)
    edge[0, 0] = True  # no border around it
    with pytest.raises(ValueError, match="beyond the mask"):
        native._polylines.order_chains(edge.ravel().view(np.uint8), offsets)
    xy = np.zeros((5, 2))
    with pytest.raises(ValueError, match="ordered ranges"):
        native._polylines.control_points(xy, np.array([0, 2]), np.array([3, 4]), 2, 1.0)
    with pytest.raises(ValueError, match="ordered ranges"):
        native._polylines.control_points(xy, np.array([0]), np.array([5]), 2, 1.0)
    with pytest.raises(ValueError, match="k >= 1"):
        native._polylines.control_points(xy, np.array([0]), np.array([4]), 0, 1.0)


def _meet_by_hand(p: np.ndarray, s: np.ndarray, i: int, j: int) -> bool:
    """Do segments i and j meet anywhere but at a shared end point?"""
    def orient(a, b, c) -> int:
        return int(np.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])))

    a, b, c, d = p[s[i, 0]], p[s[i, 1]], p[s[j, 0]], p[s[j, 1]]
    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    collinear = o1 == 0 and o2 == 0
    k = 1 if abs(b[0] - a[0]) < abs(b[1] - a[1]) else 0
    overlap = min(max(a[k], b[k]), max(c[k], d[k])) - max(min(a[k], b[k]), min(c[k], d[k]))
    if set(s[i]) & set(s[j]):
        return collinear and overlap > 0
    return (not collinear and o1 * o2 <= 0 and o3 * o4 <= 0) or (collinear and overlap >= 0)


@pytest.mark.parametrize("seed", range(20))
def test_a_wall_segment_goes_when_an_earlier_one_meets_it(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    size = int(rng.integers(3, 40))
    p = np.unique(rng.integers(0, size, (int(rng.integers(2, 40)), 2)), axis=0).astype(np.int64)
    s = rng.integers(0, len(p), (int(rng.integers(1, 60)), 2))
    # runs of consecutive points too, as walls are: shared ends, collinear pieces
    s = np.concatenate([s, np.stack([np.arange(len(p) - 1), np.arange(1, len(p))], 1)])
    s = s[s[:, 0] != s[:, 1]].astype(np.int64)
    want = [any(_meet_by_hand(p, s, i, j) for i in range(j)) for j in range(len(s))]
    for cell in (1, 4, 8, 64):
        assert native._polylines.later_conflicts(p, s, cell).tolist() == want


def test_wall_conflicts_refuse_bad_input() -> None:
    p = np.array([[0, 0], [3, 3], [0, 3]], np.int64)
    with pytest.raises(ValueError, match="out of range"):
        native._polylines.later_conflicts(p, np.array([[0, 3]], np.int64), 8)
    with pytest.raises(ValueError, match="negative"):
        native._polylines.later_conflicts(-p, np.array([[0, 1]], np.int64), 8)
    with pytest.raises(ValueError, match="cell"):
        native._polylines.later_conflicts(p, np.array([[0, 1]], np.int64), 0)


def _thin_by_filters(on: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(thinned, junction, simple) of a padded mask the way trace() made them before
    codec._polylines.thin_split: each pass's neighbourhood codes by cv2.filter2D over
    the whole mask, a look-up table, the pass's colour cleared at once; then the
    neighbour count by a filter."""
    import cv2

    from codec.mesher.polylines import _REDUNDANT_U8

    def kernel(weights):
        k = np.zeros((3, 3), np.float32)
        k[_OFFSETS[:, 0] + 1, _OFFSETS[:, 1] + 1] = weights
        return k

    on = on.copy()
    for parity in (0, 1):
        code = cv2.filter2D(on.view(np.uint8), cv2.CV_8U, kernel(1 << np.arange(8)), borderType=cv2.BORDER_CONSTANT)
        redundant = cv2.LUT(code, _REDUNDANT_U8).view(bool)
        for y0 in (0, 1):
            colour = (slice(y0, None, 2), slice((y0 + parity) % 2, None, 2))
            on[colour] &= ~redundant[colour]
    count = cv2.filter2D(on.view(np.uint8), cv2.CV_8U, kernel(np.ones(8)), borderType=cv2.BORDER_CONSTANT)
    junction = on & (count >= 3)
    return on, junction, on & ~junction


@pytest.mark.parametrize("seed", range(40))
def test_thinning_in_one_pass_over_the_edge_pixels_matches_the_image_filters(seed: int) -> None:
    from codec.mesher.polylines import _REDUNDANT_U8

    rng = np.random.default_rng(seed)
    h, w = (int(v) for v in rng.integers(3, 60, 2))
    on = np.zeros((h + 2, w + 2), bool)
    on[1:-1, 1:-1] = rng.random((h, w)) < rng.uniform(0.05, 0.8)
    want = _thin_by_filters(on)
    flat = on.ravel().copy()
    junction, simple = native._polylines.thin_split(flat.view(np.uint8), w + 2, _REDUNDANT_U8)
    assert (flat == want[0].ravel()).all()
    assert (junction == want[1].ravel()).all() and (simple == want[2].ravel()).all()


def test_thinning_refuses_a_mask_without_its_empty_border() -> None:
    from codec.mesher.polylines import _REDUNDANT_U8

    on = np.zeros((5, 6), np.uint8)
    on[0, 2] = 1
    with pytest.raises(ValueError, match="border"):
        native._polylines.thin_split(on.ravel(), 6, _REDUNDANT_U8)
    with pytest.raises(ValueError, match="256"):
        native._polylines.thin_split(np.zeros(30, np.uint8), 6, _REDUNDANT_U8[:10])
    with pytest.raises(ValueError, match="3 x 3"):
        native._polylines.thin_split(np.zeros(31, np.uint8), 6, _REDUNDANT_U8)

"""The vertex steps (ATM.md §4.2.2) two vertices at a time (codec/_fields.pyx's
atm_steps_of_fans2, SSE2 on x86-64) against the rule's arithmetic one vertex at a
time in numpy's binary64: the encoder and the decoder both take these steps, so they
must be the same integers whatever the path, rounding ties and clamps included."""

from __future__ import annotations

import math

import numpy as np

from codec.meshcode import STEP_RANGE
from codec.native import _fields


def _expected(fan: np.ndarray, step: int, bound: float) -> np.ndarray:
    """_steps_of_fans' rule, a vertex at a time."""
    out = np.full(len(fan), step, np.int64)
    positive = fan > 0
    if step <= 1 or not positive.any():
        return out
    mean = np.float64(int(fan[positive].sum())) / np.float64(int(positive.sum()))
    least = 1.0 / bound
    for i in np.nonzero(positive)[0]:
        factor = math.sqrt(mean / np.float64(int(fan[i])))
        factor = least if factor < least else (bound if factor > bound else factor)
        s = np.rint(np.float64(step) * factor)
        out[i] = int(min(max(s, 1.0), 65535.0))
    return out


def _steps(fan: np.ndarray, step: int, bound: float) -> np.ndarray:
    """The kernel's steps for these fan areas: triangle (i, i, i) of doubled area a
    adds 3a to vertex i's fan."""
    n = len(fan)
    assert (fan % 3 == 0).all()
    have = np.nonzero(fan)[0]
    triangles = np.ascontiguousarray(np.repeat(have[:, None], 3, 1), dtype=np.int64)
    return _fields.vertex_steps(triangles, np.ascontiguousarray(fan[have] // 3), n, step, bound)


def test_pairs_give_the_rules_steps() -> None:
    """Random fans (zero and negative ones among them, even and odd counts so that
    the last vertex is the scalar tail's), steps 2 to 65,535 and bounds below 1 (the
    clamps' order shows), the codec's 4, and large (steps clamped at 65,535)."""
    rng = np.random.default_rng(4031)
    for case in range(400):
        n = int(rng.integers(1, 60))
        fan = 3 * rng.integers(1, int(rng.choice([4, 100, 10**6, 10**12])), n)
        fan[rng.random(n) < 0.2] = 0
        fan[rng.random(n) < 0.05] *= -1
        step = int(rng.choice([2, 3, 7, 255, 4097, 65535]))
        bound = float(rng.choice([0.5, STEP_RANGE, 1000.0]))
        assert np.array_equal(_steps(fan, step, bound), _expected(fan, step, bound)), (case, fan, step, bound)


def test_rounding_ties_go_to_even() -> None:
    """Fans 3 * (4, 14): a mean of 9 and a factor of exactly 1.5 for the first vertex,
    so odd steps land on a half (4.5 -> 4, 7.5 -> 8, 10.5 -> 10), in either lane."""
    for fan in ([12, 42], [42, 12], [12, 42, 0], [0, 12, 42]):
        fan = np.array(fan, np.int64)
        for step in (3, 5, 7, 9):
            got = _steps(fan, step, STEP_RANGE)
            assert np.array_equal(got, _expected(fan, step, STEP_RANGE)), (fan, step, got)
            assert got[list(fan).index(12)] == int(np.rint(1.5 * step))

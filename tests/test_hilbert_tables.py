"""The Hilbert tables every encode and decode shares (codec.coding) cannot be changed
by one caller under the others."""

from __future__ import annotations

import numpy as np
import pytest

from codec import coding


def test_cached_tables_are_read_only() -> None:
    tables = [*coding.hilbert_tables(9)[:2], *coding.hilbert_inverse_tables()]
    for table in tables:
        with pytest.raises(ValueError):
            table[0] = 1
    # the same keys after every attempt, and the same keys as a fresh computation
    x, y = np.arange(512) % 512, np.arange(512) // 2
    keys = coding.hilbert_keys(x, y, 9)
    assert np.array_equal(coding.hilbert_points(keys, 9)[0], x)
    assert np.array_equal(keys, coding.hilbert_keys(x.copy(), y.copy(), 9))


def test_a_caller_cannot_move_the_curve() -> None:
    digit = coding.hilbert_tables(4)[0]
    before = coding.hilbert_keys(np.arange(16), np.arange(16), 4)
    with pytest.raises(ValueError):
        digit += 1
    assert np.array_equal(coding.hilbert_keys(np.arange(16), np.arange(16), 4), before)

"""An adaptive multi-symbol range coder in pure Python, to check that the study's
adaptive code lengths (benchmarks/range_study.py) are bytes a real coder reaches.
Slow (crops, not whole images); a measuring tool, not the codec's coder.

The coder is the carry-less range coder of D. Subbotin (32-bit low and range, bytes
out); each context keeps integer frequencies scale * count + 1 per symbol, i.e. the
study's pseudo-count 1 / scale, halved when their total nears the coder's precision.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

MASK = 0xFFFFFFFF
TOP = 1 << 24
BOT = 1 << 16  # totals must stay below this


class Model:
    """Adaptive frequencies of `alphabet` symbols in one context."""

    def __init__(self, alphabet: int, scale: int) -> None:
        self.scale = scale
        self.freq = [1] * alphabet
        self.total = alphabet

    def interval(self, symbol: int) -> tuple[int, int, int]:
        return sum(self.freq[:symbol]), self.freq[symbol], self.total

    def find(self, target: int) -> tuple[int, int, int]:
        cum = 0
        for symbol, f in enumerate(self.freq):
            if cum + f > target:
                return symbol, cum, f
            cum += f
        raise ValueError("corrupt range-coded stream")

    def update(self, symbol: int) -> None:
        self.freq[symbol] += self.scale
        self.total += self.scale
        if self.total >= BOT:
            self.freq = [(f + 1) // 2 for f in self.freq]
            self.total = sum(self.freq)


def _unsettled(low: int, rng: int) -> int | None:
    """None when no byte is ready to go out (the interval's top byte is not settled yet
    and its range is still wide); else the range to shift a byte out with, narrowed to
    the next BOT boundary when the range got too small before its top byte settled
    (Subbotin's carry-less trick)."""
    if (low ^ (low + rng)) >= TOP:
        if rng >= BOT:
            return None
        return -low & (BOT - 1)
    return rng


def encode(items: Iterable[tuple[int, int]], models: dict[int, Model]) -> bytes:
    """Bytes of (context, symbol) pairs; models[context] adapts as it goes."""
    low, rng = 0, MASK
    out = bytearray()
    for ctx, symbol in items:
        model = models[ctx]
        cum, freq, total = model.interval(symbol)
        rng //= total
        low = (low + cum * rng) & MASK
        rng *= freq
        while (narrowed := _unsettled(low, rng)) is not None:
            out.append(low >> 24)
            low = (low << 8) & MASK
            rng = (narrowed << 8) & MASK
        model.update(symbol)
    for _ in range(4):
        out.append(low >> 24)
        low = (low << 8) & MASK
    return bytes(out)


def decode(data: bytes, contexts: Iterable[int], models: dict[int, Model]) -> Iterator[int]:
    """The symbols of `data`, given each one's context in coding order (a decoder knows
    them from what it decoded before)."""
    pos = 0

    def byte() -> int:
        nonlocal pos
        b = data[pos] if pos < len(data) else 0
        pos += 1
        return b

    low, rng, code = 0, MASK, 0
    for _ in range(4):
        code = (code << 8) | byte()
    for ctx in contexts:
        model = models[ctx]
        rng //= model.total
        target = min(((code - low) & MASK) // rng, model.total - 1)
        symbol, cum, freq = model.find(target)
        low = (low + cum * rng) & MASK
        rng *= freq
        while (narrowed := _unsettled(low, rng)) is not None:
            code = ((code << 8) | byte()) & MASK
            low = (low << 8) & MASK
            rng = (narrowed << 8) & MASK
        model.update(symbol)
        yield symbol

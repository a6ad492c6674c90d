"""A short run of the structure-aware fuzzer, so CI guards what fuzz/ checks at length."""

from __future__ import annotations

import random
from pathlib import Path

from fuzz.mutate import mutate, split
from fuzz.targets import run_one

ROOT = Path(__file__).resolve().parent.parent
SEEDS = sorted((ROOT / "format_spec" / "conformance").glob("*.atm"))


def test_mutator_keeps_the_framing_most_of_the_time():
    data = SEEDS[0].read_bytes()
    rng = random.Random(1)
    framed = sum(split(mutate(data, rng)) is not None for _ in range(200))
    assert framed > 150


def test_smoke_fuzz_decoders():
    """3,000 mutated files: each decodes or raises ATMError, nothing else; some of them
    must get through validation, or the run tested only the checksums."""
    seeds = [p.read_bytes() for p in SEEDS]
    rng = random.Random(20261122)
    decoded = 0
    for _ in range(3000):
        data = rng.choice(seeds)
        for _ in range(rng.randint(1, 3)):
            data = mutate(data, rng)
        decoded += run_one(data)  # raises anything but ATMError
    assert decoded > 100

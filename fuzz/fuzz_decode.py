#!/usr/bin/env python3
"""Coverage-guided fuzzing of the .atm decoder with atheris.

    python fuzz/fuzz_decode.py -max_total_time=600         # or: fuzz/run.sh 600

Every input must decode or raise codec.ATMError; anything else is a crash and
libFuzzer writes the input to crash-* (fuzz/run.sh: in fuzz/crashes/). Once fixed, a
crash becomes a test that builds its input (fuzz/README.md).
Most mutations come from fuzz/mutate.py, which keeps the chunk framing, zstd and the
CRCs valid so that the decoder's validation is reached; the rest are libFuzzer's own.
"""

from __future__ import annotations

import random
import sys
from pathlib import Path

import atheris

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

# coverage of the codec, its format and the harness: instrumenting numpy, json and
# construct as well made every execution some four times slower
with atheris.instrument_imports(include=["codec", "format_spec", "fuzz"]):
    import codec
    import codec.container
    import codec.decoder_cpu
    import codec.mesh
    import codec.stream
    from fuzz.mutate import mutate
    from fuzz.targets import run_one


def TestOneInput(data: bytes) -> None:
    run_one(data)


def CustomMutator(data: bytes, max_size: int, seed: int) -> bytes:
    rng = random.Random(seed)
    if rng.random() < 0.2:
        return atheris.Mutate(data, max_size)
    return mutate(data, rng)[:max_size]


def main() -> None:
    atheris.Setup(sys.argv, TestOneInput, custom_mutator=CustomMutator)
    atheris.Fuzz()


if __name__ == "__main__":
    main()

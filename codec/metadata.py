"""The `meta` chunk's JSON (format_spec/ATM.md §4.7): strict RFC 8259 text of one object,
its nesting and size bounded (codec.limits), on both the encoding and the decoding side.

Python's json module accepts NaN and Infinity, turns 1e999 into inf, lets escaped lone
surrogates through and recurses once per nesting level; each of those reached a caller
as a crash or as JSON that other tools refuse. Here they are refused with an ATMError.
"""

from __future__ import annotations

import json
import re

import numpy as np

from . import limits
from .errors import CorruptError, LimitError, OptionError

#: A JSON string literal (after which brackets inside strings no longer count).
_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_OPEN = np.zeros(256, np.int8)
_OPEN[[ord("["), ord("{")]] = 1
_OPEN[[ord("]"), ord("}")]] = -1
_OPEN.flags.writeable = False


def depth(text: bytes) -> int:
    """The deepest nesting of arrays and objects in JSON text (without recursion: the
    brackets outside string literals, summed)."""
    bare = np.frombuffer(_STRING.sub(b'""', text), np.uint8)
    if not len(bare):
        return 0
    return int(np.cumsum(_OPEN[bare], dtype=np.int64).max(initial=0))


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def _finite_float(text: str) -> float:
    value = float(text)
    if not np.isfinite(value):
        raise ValueError(f"the number {text[:40]} is beyond a double's range")
    return value


def _unique_object(pairs: list[tuple[str, object]]) -> dict:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen: set[str] = set()
        dup = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise ValueError(f"the key {dup[:40]!r} appears twice in one object")
    return out


def _check_strings(value: object) -> None:
    """ValueError if any string holds a lone surrogate (an escape such as \\ud800
    that no UTF-8 text can carry). Iterative: the depth is already bounded, but a
    walk need not rely on it."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, str):
            item.encode("utf-8")  # UnicodeEncodeError (a ValueError) on a lone surrogate
        elif isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)


def parse(raw: bytes, where: str) -> dict:
    """The object of a decompressed meta chunk; CorruptError unless it is strict JSON
    of one object within the depth limit (a LimitError beyond it)."""
    if depth(raw) > limits.MAX_METADATA_DEPTH:
        raise LimitError(
            f"{where} nests JSON deeper than {limits.MAX_METADATA_DEPTH} levels "
            "(raise codec.limits.MAX_METADATA_DEPTH to accept it)"
        )
    try:
        meta = json.loads(
            raw.decode("utf-8"),
            parse_constant=_reject_constant,
            parse_float=_finite_float,
            object_pairs_hook=_unique_object,
        )
        _check_strings(meta)
    except UnicodeDecodeError:
        raise CorruptError(f"{where} is not UTF-8 text") from None
    except (ValueError, RecursionError) as exc:
        reason = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise CorruptError(f"{where} is not strict JSON (RFC 8259): {reason}") from None
    if not isinstance(meta, dict):
        raise CorruptError(f"{where} is not a JSON object")
    return meta


def encode(metadata: dict) -> bytes:
    """The meta chunk's JSON: an object, keys sorted (the same input gives the same
    bytes); OptionError for what parse() would refuse."""
    if not isinstance(metadata, dict) or not all(isinstance(k, str) for k in metadata):
        raise OptionError("metadata must be a dict with string keys")
    try:
        data = json.dumps(metadata, sort_keys=True, ensure_ascii=False, allow_nan=False).encode("utf-8")
    except RecursionError:
        data = None
    except (TypeError, ValueError) as exc:  # also lone surrogates (UnicodeEncodeError)
        raise OptionError(f"metadata must be JSON-serialisable: {exc}") from None
    if data is None or depth(data) > limits.MAX_METADATA_DEPTH:
        raise OptionError(f"metadata nests deeper than {limits.MAX_METADATA_DEPTH} levels")
    if len(data) > limits.MAX_METADATA_BYTES:
        raise OptionError(f"metadata is {len(data):,} bytes of JSON; at most {limits.MAX_METADATA_BYTES:,}")
    return data

"""A failing ``assert left == right`` on large values fails in milliseconds, under CI too
(registered by tests/conftest.py).

With ``CI`` set, pytest renders the whole difference of a failing comparison (it truncates only
elsewhere): difflib over the reprs of two checkpoints' bytes or of two long lists of floats takes
minutes to hours, so a run that should fail in seconds times out instead. A hook's answer does
not stop pytest's own explanation from being built, so for operands whose repr is longer than
`LIMIT` this hook raises the short explanation itself: sizes, the first difference, how many
positions differ, digests.

Tests compare large values by digest or with ``numpy.testing`` in the first place; this is the
net under a comparison that slips through.
"""

from __future__ import annotations

import contextlib
import hashlib
import reprlib
from collections.abc import Mapping, Sequence

import pytest

#: Longest repr (characters, of either operand) that pytest's own explanation gets.
LIMIT = 10_000

_short = reprlib.Repr()
_short.maxstring = _short.maxother = 60


def _digest(value: object) -> str | None:
    if isinstance(value, bytes | bytearray | memoryview):
        return hashlib.sha256(value).hexdigest()[:16]
    if isinstance(value, str):
        return hashlib.sha256(value.encode("utf-8", "surrogatepass")).hexdigest()[:16]
    return None


def _describe(value: object) -> str:
    size = f" of length {len(value):,}" if isinstance(value, Sequence | Mapping) else ""
    digest = _digest(value)
    return type(value).__name__ + size + (f" (sha256 {digest}…)" if digest else "")


def _first_difference(left: object, right: object) -> list[str]:
    if isinstance(left, Mapping) and isinstance(right, Mapping):
        only_left, only_right = left.keys() - right.keys(), right.keys() - left.keys()
        differ = [k for k in left.keys() & right.keys() if left[k] != right[k]]
        lines = [f"{len(differ)} common key(s) differ, {len(only_left)} only left, "
                 f"{len(only_right)} only right"]  # fmt: skip
        for key in differ[:1]:
            lines.append(f"at key {_short.repr(key)}: {_short.repr(left[key])} != "
                         f"{_short.repr(right[key])}")  # fmt: skip
        return lines
    if isinstance(left, bytes | bytearray) and isinstance(right, bytes | bytearray):
        import numpy as np

        count = min(len(left), len(right))
        a, b = (np.frombuffer(v, np.uint8, count) for v in (left, right))
        differ = np.flatnonzero(a != b).tolist()
    elif isinstance(left, Sequence) and isinstance(right, Sequence):
        count = min(len(left), len(right))
        differ = [i for i in range(count) if left[i] != right[i]]
    else:
        return []
    lines = [f"{len(differ):,} of the first {count:,} positions differ"]
    if differ:
        i = differ[0]
        lines.append(f"first at index {i:,}: {_short.repr(left[i])} != "
                     f"{_short.repr(right[i])}")  # fmt: skip
    return lines


@pytest.hookimpl(tryfirst=True)
def pytest_assertrepr_compare(config, op: str, left: object, right: object):
    """Fail at once with a short explanation when ``left == right`` fails on large operands."""
    __tracebackhide__ = True
    if op != "==":
        return None
    try:
        large = max(len(repr(left)), len(repr(right))) > LIMIT
    except Exception:  # an object whose repr fails: leave it to pytest
        return None
    if not large:
        return None
    lines = [f"{_describe(left)} == {_describe(right)}: not equal"]
    # Elements that do not compare to a bool (arrays) leave sizes and digests only.
    with contextlib.suppress(Exception):
        lines += _first_difference(left, right)
    lines.append(f"(the full difference is not rendered: a repr beyond {LIMIT:,} characters; "
                 "compare large values by digest or with numpy.testing)")  # fmt: skip
    raise AssertionError("\n".join(lines))

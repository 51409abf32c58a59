"""The cells of the report's tables: numbers, intervals, bin ranges, and a Markdown table of
them (what ``report.md``, the printed table and every measure's section share)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def number(value: float | None, digits: int = 3) -> str:
    """``0.357``; ``–`` for a missing value."""
    return "–" if value is None else f"{value:.{digits}f}"


def with_ci(value: float | None, ci: Sequence[float] | None, digits: int = 3) -> str:
    """``0.357 [0.331, 0.384]``; the value alone when there is no interval."""
    if value is None or not ci:
        return number(value, digits)
    return f"{value:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def bin_range(row: dict[str, Any]) -> str:
    """A bin's delentropy range, ``[3.10, 4.20]``."""
    return f"[{number(row.get('lo'), 2)}, {number(row.get('hi'), 2)}]"


def md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table's lines, then a blank line."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return [*lines, *("| " + " | ".join(row) + " |" for row in rows), ""]

"""The cells of the report's tables: numbers, intervals, bin ranges, and a Markdown table of
them (what ``report.md``, the printed table and every measure's section share)."""

from __future__ import annotations

import math
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


def points_digits(values: Sequence[float | None], most: int = 4) -> int:
    """Decimals for gaps in mIoU points: 1, or as many as the smallest non-zero value needs to
    show its first significant digit (at most ``most``), so that a gap of 0.003 points with an
    interval that excludes 0 is not written ``+0.0 [+0.0, +0.0]``."""
    small = min((abs(v) for v in values if v), default=None)
    if small is None or small >= 0.05:
        return 1
    return min(most, max(1, math.ceil(-math.log10(small))))


def _p_value(p: float | None, resamples: int) -> str:
    """A p-value; 0 (no resample on the other side) is written as below 1/R."""
    if p is None:
        return "–"
    return f"< {1 / resamples:.2g}" if p == 0 and resamples else f"{p:.3f}"


def gap_cell(row: dict[str, Any], resamples: int) -> list[str]:
    """Gap in mIoU points with its interval, the p-value, and a mark when 0 is outside."""
    gap, ci = row.get("gap"), row.get("gap_ci")
    if gap is None:
        return ["–", "–", ""]
    points = [100 * v for v in (gap, *(ci or []))]
    d = points_digits(points)
    text = f"{points[0]:+.{d}f}"
    if ci:
        text += f" [{points[1]:+.{d}f}, {points[2]:+.{d}f}]"
    p = row.get("p_value")
    if not ci:  # no interval (--bootstrap 0, too few clusters): nothing to exclude
        return [text, _p_value(p, resamples), "–"]
    excludes = ci[0] > 0 or ci[1] < 0
    return [text, _p_value(p, resamples), "**yes**" if excludes else "no"]

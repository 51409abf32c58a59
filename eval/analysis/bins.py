"""Complexity bins: which images fall in which delentropy range (docs/evaluation.md).

- Quantile bins: sort images by (complexity, path) and split the order into K contiguous groups
  the way ``numpy.array_split`` does (the first ``n % K`` groups get one more image). Ties are
  broken by path, so the bins never depend on the order images were listed in.
- Fixed edges ``e_0 < e_1 < ... < e_K``: bin i holds ``e_i <= x < e_{i+1}``, the last bin is
  closed (``x <= e_K``); values outside ``[e_0, e_K]`` are in no bin (counted in the report).
  Fixed edges make reports of different models and datasets comparable.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

_NAMES = {1: ("all",), 2: ("low", "high"), 3: ("low", "medium", "high")}


@dataclass(frozen=True)
class Bin:
    """One complexity bin: its name, its range and the indices of its images."""

    name: str
    lo: float | None
    hi: float | None
    indices: tuple[int, ...]


def bin_names(k: int) -> tuple[str, ...]:
    """``low``/``medium``/``high`` for 3 bins (``low``/``high`` for 2), else ``q1`` ... ``qK``."""
    return _NAMES.get(k, tuple(f"q{i + 1}" for i in range(k)))


def parse_edges(text: str | Sequence[float]) -> list[float]:
    """Fixed edges from ``"4.0,4.5,5"`` or a sequence; strictly increasing, finite, at least 2."""
    try:
        edges = [float(v) for v in (text.split(",") if isinstance(text, str) else text)]
    except ValueError:
        raise ValueError(f"bin edges {text!r} are not numbers; write e.g. 4.0,4.5,5.0") from None
    if len(edges) < 2:
        raise ValueError(f"bin edges {edges} need at least 2 values (one bin)")
    if not all(math.isfinite(e) for e in edges):
        raise ValueError(f"bin edges {edges} must be finite numbers")
    if any(b <= a for a, b in itertools.pairwise(edges)):
        raise ValueError(f"bin edges {edges} must be strictly increasing")
    return edges


def quantile_bins(
    values: ArrayLike,
    paths: Sequence[str],
    k: int,
    *,
    order: ArrayLike | None = None,
    what: str = "images",
) -> list[Bin]:
    """K bins of (almost) equal size over the images sorted by (value, path).

    Args:
        values: one value per item.
        paths: one path per item (the tie-break).
        k: the number of bins.
        order: the items already sorted by another tie-break (tiles: value, path, row,
            column); default (value, path).
        what: what the items are, for the message.

    Raises:
        ValueError: ``k < 1``, more bins than items, a NaN value, or lengths differ.
    """
    values = np.asarray(values, dtype=np.float64)
    if order is None and len(values) != len(paths):
        raise ValueError(f"{len(values)} values for {len(paths)} paths")
    if k < 1:
        raise ValueError(f"the number of bins must be at least 1, got {k}")
    if k > len(values):
        raise ValueError(
            f"{k} bins for {len(values)} {what}: use at most {len(values)} bins (--bins)"
        )
    if np.isnan(values).any():
        raise ValueError("complexity values contain NaN: every image needs a complexity value")
    if order is None:
        order = sorted(range(len(values)), key=lambda i: (values[i], str(paths[i])))
    groups = np.array_split(np.asarray(order, dtype=np.int64), k)
    return [
        Bin(name, float(values[g].min()), float(values[g].max()), tuple(int(i) for i in g))
        for name, g in zip(bin_names(k), groups, strict=True)
    ]


def choose_bins(
    values: ArrayLike,
    paths: Sequence[str],
    measure: str,
    *,
    bins: int = 3,
    edges: Sequence[float] | None = None,
    order: ArrayLike | None = None,
    what: str = "images",
) -> tuple[list[Bin], list[int], dict[str, Any]]:
    """The bins of a report: between fixed ``edges`` when given, else ``bins`` quantile bins.

    Returns:
        ``(bins, outside, binning)``: the bins, the items outside every fixed bin, and the
        report's ``binning`` entry (``measure``, ``method``, ``edges`` or ``bins``) without
        what is outside (a report lists images, a tile report counts tiles).
    """
    if edges is not None:
        bin_list, outside = fixed_bins(values, edges)
        binning = {"measure": measure, "method": "fixed", "edges": [float(e) for e in edges]}
        return bin_list, outside, binning
    bin_list = quantile_bins(values, paths, bins, order=order, what=what)
    return bin_list, [], {"measure": measure, "method": "quantile", "bins": bins}


def fixed_bins(values: ArrayLike, edges: Sequence[float]) -> tuple[list[Bin], list[int]]:
    """Bins between fixed edges, and the indices of the images outside every bin.

    Returns:
        ``(bins, outside)``: bin i covers ``[edges[i], edges[i+1])`` (the last one closed) and
        is named by its range; empty bins are kept, so every report has the same rows.
    """
    edges = parse_edges(edges)
    values = np.asarray(values, dtype=np.float64)
    # side="right" puts a value equal to an edge into the bin that starts there.
    slot = np.searchsorted(edges, values, side="right") - 1
    slot[values == edges[-1]] = len(edges) - 2  # the last bin is closed
    inside = (slot >= 0) & (slot < len(edges) - 1) & ~np.isnan(values)
    bins = []
    for i, (lo, hi) in enumerate(itertools.pairwise(edges)):
        last = i == len(edges) - 2
        name = f"[{lo:g}, {hi:g}{']' if last else ')'}"
        members = np.flatnonzero(inside & (slot == i))
        bins.append(Bin(name, lo, hi, tuple(int(j) for j in members)))
    return bins, [int(j) for j in np.flatnonzero(~inside)]

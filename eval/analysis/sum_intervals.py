"""Intervals and paired gaps of any statistic of summed per-image rows.

mIoU is one ratio of sums over the images of a set; Boundary IoU, calibration (ECE, MCE) and
cross-view consistency are others (:mod:`claravid.eval.analysis.quality`). Each image (or pair)
stores a row of sums, a set's value is a statistic of its rows' sum, and so one cluster
bootstrap serves them all: the rows are summed per cluster, resampled as ``counts @
per_cluster`` (:func:`claravid.eval.analysis.bootstrap.resampled`), and the statistic is
taken per resample. A paired gap draws the same clusters for both reports and takes the
difference per resample, exactly as :func:`claravid.eval.analysis.bootstrap.paired_gap` does
for mIoU.

A statistic maps summed rows float64 [R, D] to values [R, S], one column per name in
``names``; a NaN value (an empty set, a class never present) is left out of the percentiles.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    draw_counts,
    draws_for,
    p_value,
    per_cluster_sums,
    percentile_interval,
    resampled,
    set_clusters,
)

Statistic = Callable[[np.ndarray], np.ndarray]


def point_values(rows: np.ndarray, members: Sequence[int], statistic: Statistic) -> np.ndarray:
    """The statistic of the summed rows of ``members`` (float64 [S]; NaN where undefined)."""
    rows = np.asarray(rows, dtype=np.float64)
    index = np.asarray(members, dtype=np.int64).reshape(-1)
    summed = rows[index].sum(axis=0, keepdims=True)
    return np.asarray(statistic(summed), dtype=np.float64).reshape(-1)


def sums_interval(
    rows: np.ndarray,
    clusters: np.ndarray,
    members: Sequence[int],
    settings: Bootstrap,
    statistic: Statistic,
    names: Sequence[str],
    *,
    counts: np.ndarray | None = None,
    stream: str = "",
) -> dict[str, Any]:
    """The percentile interval of each statistic of the summed rows of ``members``.

    Args:
        rows: float or int [N, D], one row of sums per image.
        clusters: int [N] cluster id of each image.
        members: the images of the set.
        settings: resamples, level, seed.
        statistic: summed rows [R, D] -> values [R, len(names)].
        names: the statistics' names: the result has ``<name>_ci`` for each.
        counts: fixed draw counts [R, C] (tests); None: drawn from the set's generator.
        stream: names the set's generator.

    Returns:
        ``{"<name>_ci": [lo, hi] | None, ..., "ci_note": str | None}``.
    """
    picked, local, num, note = set_clusters(clusters, members, settings, counts)
    if note is not None:
        return {**{f"{n}_ci": None for n in names}, "ci_note": note}
    rows = np.asarray(rows, dtype=np.float64)
    per_cluster = per_cluster_sums(rows[picked], local, num)
    values = resampled(draws_for(num, settings, counts, stream), per_cluster, statistic)
    values = values.reshape(len(values), -1)
    return {
        **{
            f"{n}_ci": percentile_interval(values[:, j], settings.level)
            for j, n in enumerate(names)
        },
        "ci_note": None,
    }


def _gap_entry(gap: float, gaps: np.ndarray | None, level: float) -> dict[str, Any]:
    out: dict[str, Any] = {"gap": float(gap) if np.isfinite(gap) else None, "gap_ci": None,
                           "p_value": None}  # fmt: skip
    if gaps is not None:
        out["gap_ci"] = percentile_interval(gaps, level)
        out["p_value"] = p_value(gaps, gap)
    return out


def paired_sums_gap(
    rows_a: np.ndarray,
    rows_b: np.ndarray,
    clusters: np.ndarray,
    members: Sequence[int],
    settings: Bootstrap,
    statistic: Statistic,
    names: Sequence[str],
    *,
    counts: np.ndarray | None = None,
    stream: str = "",
) -> dict[str, dict[str, Any]]:
    """Each statistic's gap B − A over the same images, the same clusters drawn for both.

    ``rows_b`` is in ``rows_a``'s image order.

    Returns:
        ``{name: {"gap", "gap_ci", "p_value", "ci_note", "paired": True}}``.
    """
    rows_a, rows_b = np.asarray(rows_a, np.float64), np.asarray(rows_b, np.float64)
    if rows_a.shape != rows_b.shape:
        raise ValueError(f"paired rows differ in shape: {rows_a.shape} vs {rows_b.shape}")
    gap = point_values(rows_b, members, statistic) - point_values(rows_a, members, statistic)
    picked, local, num, note = set_clusters(clusters, members, settings, counts)
    gaps = None
    if note is None:
        d = rows_a.shape[1]
        flat = per_cluster_sums(np.concatenate([rows_a[picked], rows_b[picked]], axis=1),
                                local, num)  # fmt: skip

        def gap_of(sums: np.ndarray) -> np.ndarray:
            b = np.asarray(statistic(sums[:, d:]), np.float64).reshape(len(sums), -1)
            a = np.asarray(statistic(sums[:, :d]), np.float64).reshape(len(sums), -1)
            return b - a

        gaps = resampled(draws_for(num, settings, counts, stream), flat, gap_of)
        gaps = gaps.reshape(len(gaps), -1)
    return {
        n: {**_gap_entry(gap[j], None if gaps is None else gaps[:, j], settings.level),
            "ci_note": note, "paired": True}
        for j, n in enumerate(names)
    }  # fmt: skip


def unpaired_sums_gap(
    rows_a: np.ndarray,
    clusters_a: np.ndarray,
    members_a: Sequence[int],
    rows_b: np.ndarray,
    clusters_b: np.ndarray,
    members_b: Sequence[int],
    settings: Bootstrap,
    statistic: Statistic,
    names: Sequence[str],
    *,
    stream: str = "",
) -> dict[str, dict[str, Any]]:
    """Each statistic's gap B − A of two different image sets, each resampled on its own
    (generators ``<stream>:a`` and ``<stream>:b``, as
    :func:`claravid.eval.analysis.bootstrap.unpaired_gap`).

    Returns:
        ``{name: {"gap", "gap_ci", "p_value", "ci_note", "paired": False}}``.
    """
    points, draws, notes = [], [], []
    for tag, rows, clusters, members in (("a", rows_a, clusters_a, members_a),
                                         ("b", rows_b, clusters_b, members_b)):  # fmt: skip
        rows = np.asarray(rows, np.float64)
        points.append(point_values(rows, members, statistic))
        picked, local, num, note = set_clusters(clusters, members, settings)
        if note is not None:
            notes.append(note)
            continue
        counts = draw_counts(num, settings.resamples, settings.rng(f"{stream}:{tag}"))
        values = resampled(counts, per_cluster_sums(rows[picked], local, num), statistic)
        draws.append(values.reshape(len(values), -1))
    gap = points[1] - points[0]
    note = "; ".join(dict.fromkeys(notes)) or None
    gaps = None if notes else draws[1] - draws[0]
    return {
        n: {**_gap_entry(gap[j], None if gaps is None else gaps[:, j], settings.level),
            "ci_note": note, "paired": False}
        for j, n in enumerate(names)
    }  # fmt: skip

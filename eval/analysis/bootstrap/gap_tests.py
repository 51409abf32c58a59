"""The gap between two reports' mIoU with its interval and two-sided p-value: paired (the same
images, resampled together) or unpaired (each report's clusters drawn on their own)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from claravid.eval.analysis.bootstrap.intervals import confusion_features, miou_acc
from claravid.eval.analysis.bootstrap.resampling import (
    Bootstrap,
    draw_counts,
    draws_for,
    per_cluster_sums,
    percentile_interval,
    resampled,
    set_clusters,
)


def p_value(resampled_gaps: np.ndarray, gap: float) -> float | None:
    """Two-sided p = min(1, 2 × share of resampled gaps on the other side of 0 from ``gap``).

    A gap of exactly 0 gets p = 1; "other side" counts resamples equal to 0 (conservative).
    """
    gaps = np.asarray(resampled_gaps, dtype=np.float64)
    gaps = gaps[np.isfinite(gaps)]
    if gaps.size == 0 or not np.isfinite(gap):
        return None
    if gap == 0:
        return 1.0
    other = gaps <= 0 if gap > 0 else gaps >= 0
    return float(min(1.0, 2.0 * other.mean()))


def _point_miou(conf: np.ndarray, members: np.ndarray) -> float:
    """mIoU of the summed confusion of ``members`` (NaN when empty)."""
    if members.size == 0:
        return float("nan")
    summed = np.asarray(conf)[members].sum(axis=0, keepdims=True)
    return float(miou_acc(confusion_features(summed), summed.shape[-1])[0][0])


def paired_gap(
    conf_a: np.ndarray,
    conf_b: np.ndarray,
    clusters: np.ndarray,
    members: ArrayLike,
    settings: Bootstrap,
    counts: np.ndarray | None = None,
    *,
    stream: str = "",
) -> dict[str, Any]:
    """mIoU gap B − A over the same images, with the same draws for both models.

    Returns:
        ``{"gap": float | None, "gap_ci": [lo, hi] | None, "p_value": float | None,
        "ci_note": str | None}``.
    """
    conf_a, conf_b = np.asarray(conf_a), np.asarray(conf_b)
    if conf_a.shape != conf_b.shape:
        raise ValueError(f"paired confusions differ in shape: {conf_a.shape} vs {conf_b.shape}")
    members, local, num, note = set_clusters(clusters, members, settings, counts)
    gap = _point_miou(conf_b, members) - _point_miou(conf_a, members)
    out: dict[str, Any] = {
        "gap": gap if np.isfinite(gap) else None,
        "gap_ci": None,
        "p_value": None,
        "ci_note": None,
    }
    if note is not None:
        return {**out, "ci_note": note}
    k = conf_a.shape[-1]
    draws = draws_for(num, settings, counts, stream)
    flat = np.concatenate(
        [confusion_features(conf_a[members]), confusion_features(conf_b[members])], axis=1
    )

    def gap_of(sums: np.ndarray) -> np.ndarray:
        return miou_acc(sums[:, 3 * k :], k)[0] - miou_acc(sums[:, : 3 * k], k)[0]

    gaps = resampled(draws, per_cluster_sums(flat, local, num), gap_of)
    return {
        **out,
        "gap_ci": percentile_interval(gaps, settings.level),
        "p_value": p_value(gaps, gap),
    }


def unpaired_gap(
    conf_a: np.ndarray,
    clusters_a: np.ndarray,
    members_a: ArrayLike,
    conf_b: np.ndarray,
    clusters_b: np.ndarray,
    members_b: ArrayLike,
    settings: Bootstrap,
    *,
    stream: str = "",
) -> dict[str, Any]:
    """mIoU gap B − A of two different image sets, each resampled independently.

    Returns:
        ``{"gap", "gap_ci", "p_value", "ci_note"}`` like :func:`paired_gap`.
    """
    conf_a, conf_b = np.asarray(conf_a), np.asarray(conf_b)
    values, point = [], []
    notes = []
    for tag, conf, clusters, members in (
        ("a", conf_a, clusters_a, members_a),
        ("b", conf_b, clusters_b, members_b),
    ):
        members, local, num, note = set_clusters(clusters, members, settings)
        k = conf.shape[-1]
        point.append(_point_miou(conf, members))
        if note is not None:
            notes.append(note)
            continue
        draws = draw_counts(num, settings.resamples, settings.rng(f"{stream}:{tag}"))
        per_cluster = per_cluster_sums(confusion_features(conf[members]), local, num)

        def miou_of(sums: np.ndarray, k: int = k) -> np.ndarray:
            return miou_acc(sums, k)[0]

        values.append(resampled(draws, per_cluster, miou_of))
    gap = point[1] - point[0]
    out: dict[str, Any] = {
        "gap": gap if np.isfinite(gap) else None,
        "gap_ci": None,
        "p_value": None,
        "ci_note": "; ".join(dict.fromkeys(notes)) or None,
    }
    if notes:
        return out
    gaps = values[1] - values[0]
    return {
        **out,
        "gap_ci": percentile_interval(gaps, settings.level),
        "p_value": p_value(gaps, gap),
    }

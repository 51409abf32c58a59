"""Intervals of the report's statistics from the resampled sums: mIoU and pixel accuracy of a
summed confusion, a mean, and the Pearson and Spearman correlations of two per-image values."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from claravid.eval.analysis.bootstrap.resampling import (
    CHUNK,
    Bootstrap,
    draws_for,
    per_cluster_sums,
    percentile_interval,
    resampled,
    set_clusters,
)

#: The fewest image pairs, and clusters, a correlation interval is computed from: with 3
#: points every resample holding all three gives the same r (a zero-width "interval"), and 3
#: clusters have only 10 distinct resamples.
MIN_CORRELATION = 4


def confusion_features(confusions: np.ndarray) -> np.ndarray:
    """What mIoU and pixel accuracy need of each confusion [M,K,K]: float64 [M, 3K] =
    (true positives, ground-truth totals, predicted totals). Resampling these sums instead of
    the K×K cells is K/3 times less work and gives the same numbers (integer sums stay exact
    in float64 below 2^53 pixels)."""
    conf = np.asarray(confusions)
    tp = np.diagonal(conf, axis1=1, axis2=2)
    return np.concatenate([tp, conf.sum(axis=2), conf.sum(axis=1)], axis=1).astype(np.float64)


def miou_acc(features: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """mIoU (NaN-mean over classes with union > 0) and pixel accuracy from summed features."""
    tp, truth, predicted = features[:, :k], features[:, k : 2 * k], features[:, 2 * k : 3 * k]
    union = truth + predicted - tp
    present = union > 0
    iou = np.where(present, tp / np.where(present, union, 1.0), 0.0)
    count = present.sum(axis=1)
    total = truth.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        miou = np.where(count > 0, iou.sum(axis=1) / np.maximum(count, 1), np.nan)
        acc = np.where(total > 0, tp.sum(axis=1) / np.where(total > 0, total, 1.0), np.nan)
    return miou, acc


def confusion_interval(
    confusions: np.ndarray,
    clusters: np.ndarray,
    members: ArrayLike,
    settings: Bootstrap,
    counts: np.ndarray | None = None,
    *,
    stream: str = "",
    features: np.ndarray | None = None,
) -> dict[str, Any]:
    """Intervals of the mIoU and pixel accuracy of the summed confusion of ``members``.

    Args:
        confusions: int [N,K,K] per-image confusions.
        clusters: int [N] cluster id of each image (:func:`cluster_ids`).
        members: the images of the set (bin, group, all).
        settings: resamples, level, seed.
        counts: optional [R, C] draw counts over the members' C distinct clusters in sorted
            cluster-id order (tests pass a fixed matrix); drawn from ``settings`` when None.
        stream: names the set's generator (e.g. ``"bin:low"``).
        features: :func:`confusion_features` of all N confusions, computed once by a caller
            that asks for many sets (then ``confusions`` only gives K).

    Returns:
        ``{"miou_ci": [lo, hi] | None, "pixel_acc_ci": [lo, hi] | None, "ci_note": str | None}``.
    """
    confusions = np.asarray(confusions)
    members, local, num, note = set_clusters(clusters, members, settings, counts)
    if note is not None:
        return {"miou_ci": None, "pixel_acc_ci": None, "ci_note": note}
    k = confusions.shape[-1]
    rows = features[members] if features is not None else confusion_features(confusions[members])
    per_cluster = per_cluster_sums(rows, local, num)
    draws = draws_for(num, settings, counts, stream)
    both = resampled(draws, per_cluster, lambda sums: np.stack(miou_acc(sums, k), axis=1))
    miou, acc = both[:, 0], both[:, 1]
    return {
        "miou_ci": percentile_interval(miou, settings.level),
        "pixel_acc_ci": percentile_interval(acc, settings.level),
        "ci_note": None,
    }


def mean_interval(
    values: np.ndarray,
    clusters: np.ndarray,
    members: ArrayLike,
    settings: Bootstrap,
    counts: np.ndarray | None = None,
    *,
    stream: str = "",
) -> dict[str, Any]:
    """Mean of a per-image metric over ``members`` and its interval.

    A resample's mean is over the images of its drawn clusters, each counted as often as its
    cluster was drawn. Images with a non-finite value are left out (before clusters are taken).

    Returns:
        ``{"mean": float | None, "ci": [lo, hi] | None, "ci_note": str | None}``.
    """
    values = np.asarray(values, dtype=np.float64)
    finite = np.asarray(members, dtype=np.int64).reshape(-1)
    finite = finite[np.isfinite(values[finite])]
    mean = float(values[finite].mean()) if finite.size else None
    members, local, num, note = set_clusters(clusters, finite, settings, counts)
    if note is not None:
        return {"mean": mean, "ci": None, "ci_note": note}
    rows = np.stack([values[members], np.ones(len(members))], axis=1)
    per_cluster = per_cluster_sums(rows, local, num)
    means = resampled(draws_for(num, settings, counts, stream), per_cluster,
                       lambda sums: sums[:, 0] / sums[:, 1])  # fmt: skip
    return {
        "mean": mean,
        "ci": percentile_interval(means, settings.level),
        "ci_note": None,
    }


def _weighted_pearson(weights: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pearson r of (x, y) per row of frequency ``weights`` [R, N]; NaN without spread."""
    x = x - x.mean()
    y = y - y.mean()  # centring first keeps the moment formulas accurate
    total = weights.sum(axis=1)
    mx, my = weights @ x / total, weights @ y / total
    sxy = weights @ (x * y) / total - mx * my
    sxx = weights @ (x * x) / total - mx * mx
    syy = weights @ (y * y) / total - my * my
    with np.errstate(invalid="ignore", divide="ignore"):
        r = sxy / np.sqrt(sxx * syy)
    spread = (sxx > 1e-12 * max(float(np.mean(x * x)), 1e-300)) & (
        syy > 1e-12 * max(float(np.mean(y * y)), 1e-300)
    )
    return np.where(spread & ((weights > 0).sum(axis=1) >= 3), np.clip(r, -1.0, 1.0), np.nan)


def _weighted_ranks(weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Average ranks (1-based, ties averaged) of x in each row's weighted multiset -> [R, N]."""
    uniq, inverse = np.unique(x, return_inverse=True)
    u, r = len(uniq), weights.shape[0]
    offsets = (np.arange(r) * u)[:, None]
    per_value = np.bincount((offsets + inverse[None, :]).ravel(), weights.ravel(), minlength=r * u)
    per_value = per_value.reshape(r, u)
    below = np.cumsum(per_value, axis=1) - per_value  # weight of smaller values
    rank_of_value = below + (per_value + 1.0) / 2.0
    return rank_of_value[:, inverse]


def correlation_interval(
    x: np.ndarray,
    y: np.ndarray,
    clusters: np.ndarray,
    settings: Bootstrap,
    counts: np.ndarray | None = None,
    *,
    stream: str = "",
) -> dict[str, Any]:
    """Intervals of Pearson and Spearman correlations of per-image pairs (x_i, y_i).

    Clusters are resampled; the pairs of the images of a drawn cluster are kept together (each
    counted as often as its cluster was drawn). Pairs with a non-finite value are left out.
    Spearman ranks are recomputed in each resampled multiset (ties averaged).

    Returns:
        ``{"pearson_ci", "spearman_ci", "ci_note"}``.
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    keep = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    members, local, num, note = set_clusters(clusters, keep, settings, counts)
    if note is None and min(len(members), num) < MIN_CORRELATION:
        note = (
            f"{len(members)} image pairs in {num} {settings.cluster} clusters: a correlation "
            f"interval needs at least {MIN_CORRELATION} of each"
        )
    if note is not None:
        return {"pearson_ci": None, "spearman_ci": None, "ci_note": note}
    draws = draws_for(num, settings, counts, stream)
    xs, ys = x[members], y[members]
    pearson, spearman = [], []
    for start in range(0, draws.shape[0], CHUNK):
        weights = draws[start : start + CHUNK][:, local].astype(np.float64)
        pearson.append(_weighted_pearson(weights, xs, ys))
        rx, ry = _weighted_ranks(weights, xs), _weighted_ranks(weights, ys)
        spearman.append(_rowwise_pearson(weights, rx, ry))
    return {
        "pearson_ci": percentile_interval(np.concatenate(pearson), settings.level),
        "spearman_ci": percentile_interval(np.concatenate(spearman), settings.level),
        "ci_note": None,
    }


def _rowwise_pearson(weights: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Weighted Pearson r per row where x and y differ per row too ([R, N] each)."""
    total = weights.sum(axis=1, keepdims=True)
    mx = (weights * x).sum(axis=1, keepdims=True) / total
    my = (weights * y).sum(axis=1, keepdims=True) / total
    dx, dy = x - mx, y - my
    sxy = (weights * dx * dy).sum(axis=1)
    sxx = (weights * dx * dx).sum(axis=1)
    syy = (weights * dy * dy).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = sxy / np.sqrt(sxx * syy)
    ok = (sxx > 0) & (syy > 0) & ((weights > 0).sum(axis=1) >= 3)
    return np.where(ok, np.clip(r, -1.0, 1.0), np.nan)

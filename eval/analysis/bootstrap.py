"""Cluster percentile bootstrap for the report's numbers (docs/evaluation.md).

Neighbouring ClaraVid frames overlap, so images are not independent samples: the resampled
unit is a *cluster* of dependent images (a spatial block, a UAVid sequence, a folder, or the
image itself). For a set of images (a bin, a group, the whole split):

1. take the distinct clusters of its images (C of them, in sorted cluster-id order);
2. draw C clusters with replacement, R times: a draw-count matrix ``counts[r, c]`` (how many
   times resample r drew cluster c);
3. take every image of the set in each drawn cluster, as often as the cluster was drawn: the
   resampled summed confusion is ``counts @ per_cluster_confusion`` (one matrix product, not a
   Python loop per resample);
4. compute the statistic (mIoU from the summed confusion, pixel accuracy, a mean, a
   correlation) per resample; the interval is the percentile interval of the R values
   (``numpy.quantile``, linear interpolation, at ``(1 - level) / 2`` and ``(1 + level) / 2``).

Bins are not recomputed per resample. Each set draws from its own generator,
``numpy.random.default_rng([seed, crc32(stream)])``, so a bin's interval depends on the seed
and its own images only, never on the other bins; the same seed gives identical numbers.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from claravid.eval.analysis.units import CLUSTER_UNITS
from claravid.infra.memory import available_memory

METHOD = "cluster percentile bootstrap"
#: Resamples per matrix product: bounds the memory of the float64 draw-count block.
_CHUNK = 256
#: Cells counted per bincount in :func:`draw_counts` (~L2-sized).
_CACHE_CELLS = 32768
#: The fewest resamples an interval may rest on. A 95 % percentile interval reads the 2.5th and
#: 97.5th percentiles: with 100 resamples each end rests on 2-3 values (with 1, 2 or 5 it is
#: an extreme value or an interpolation that can exclude the estimate). Efron & Tibshirani
#: advise 1000 or more for percentile intervals; 100 is the floor, 1000 the default.
MIN_RESAMPLES = 100
#: Bytes a bootstrap holds per resample beside its draw counts (4 bytes per cluster): the
#: resampled statistics, 8-byte floats (mIoU and pixel accuracy, a model's mIoU, a gap, a
#: Pearson and a Spearman r), the finite values a percentile interval keeps and the copy
#: ``numpy.quantile`` sorts: at most 8 of them at a time. The resampled sums themselves are
#: made and reduced :data:`_CHUNK` resamples at a time, so they do not grow with R.
_BYTES_PER_RESAMPLE = 64
#: The fewest image pairs, and clusters, a correlation interval is computed from: with 3
#: points every resample holding all three gives the same r (a zero-width "interval"), and 3
#: clusters have only 10 distinct resamples.
MIN_CORRELATION = 4


@dataclass(frozen=True)
class Bootstrap:
    """Bootstrap settings.

    Attributes:
        resamples: R, the number of resamples; 0 switches intervals off.
        level: the interval's coverage, in (0, 1).
        seed: the seed of every generator (same seed, same numbers).
        cluster: the resampled unit's name (one of :data:`CLUSTER_UNITS`), reported as is.
    """

    resamples: int = 1000
    level: float = 0.95
    seed: int = 0
    cluster: str = "image"

    def __post_init__(self) -> None:
        # The one validation of these settings: the command line builds a Bootstrap from its
        # flags, so each message names the flag beside the setting.
        if isinstance(self.resamples, bool) or not isinstance(self.resamples, (int, np.integer)):
            raise ValueError(f"--bootstrap (resamples) must be an integer, got {self.resamples!r}")
        if self.resamples < 0:
            raise ValueError(
                f"--bootstrap (resamples) must be >= 0 (0 switches intervals off), got "
                f"{self.resamples}"
            )
        if 0 < self.resamples < MIN_RESAMPLES:
            raise ValueError(
                f"--bootstrap (resamples) {self.resamples} is too few for a percentile interval: "
                f"use at least {MIN_RESAMPLES} (1000 is usual), or 0 to switch intervals off"
            )
        if not 0.0 < float(self.level) < 1.0:
            raise ValueError(
                f"--ci-level (the interval level) must be between 0 and 1 (e.g. 0.95), got "
                f"{self.level}"
            )
        if self.cluster not in CLUSTER_UNITS:
            raise ValueError(
                f"unknown --cluster {self.cluster!r} (the resampled unit); use one of "
                f"{', '.join(CLUSTER_UNITS)}"
            )
        if self.seed < 0:
            raise ValueError(f"--seed (the bootstrap seed) must be >= 0, got {self.seed}")

    @property
    def enabled(self) -> bool:
        """Whether intervals are computed at all."""
        return self.resamples > 0

    def check_memory(self, clusters: Sequence[Any] | int) -> None:
        """Refuse, before anything is allocated, intervals that would not fit in memory: the
        one check of every path that resamples (evaluation, merge, comparison, ``scores``,
        tiles), called first by each and by :func:`draw_counts`.

        Args:
            clusters: the cluster label of each image (or the number of clusters): the most
                clusters any set of these images draws from.

        Raises:
            ValueError: the bootstrap needs more than the memory available (one line naming
                the size and ``--bootstrap``).
        """
        if not self.enabled:
            return
        num = clusters if isinstance(clusters, int) else len(set(map(str, clusters)))
        check_resamples(self.resamples, num)

    def rng(self, stream: str = "") -> np.random.Generator:
        """The generator of one set (bin, group, overall), named by ``stream``."""
        return np.random.default_rng([int(self.seed), zlib.crc32(stream.encode("utf-8"))])

    def describe(self, num_clusters: int) -> dict[str, Any]:
        """The report's top-level ``uncertainty`` entry."""
        return {
            "method": METHOD,
            "resamples": int(self.resamples),
            "cluster": self.cluster,
            "num_clusters": int(num_clusters),
            "level": float(self.level),
            "seed": int(self.seed),
        }


def cluster_ids(labels: Sequence[str]) -> np.ndarray:
    """Integer cluster ids (int64 [N]) of per-image cluster labels, numbered in sorted label
    order, so the ids never depend on the order images were listed in."""
    names = np.asarray([str(label) for label in labels], dtype=str)
    if names.size == 0:
        return np.zeros(0, dtype=np.int64)
    _, inverse = np.unique(names, return_inverse=True)
    return inverse.astype(np.int64).reshape(-1)


def draw_counts(num_clusters: int, resamples: int, rng: np.random.Generator) -> np.ndarray:
    """Draw ``num_clusters`` clusters with replacement, ``resamples`` times.

    Returns:
        int32 [R, C]: ``counts[r, c]`` = how many times resample r drew cluster c; every row
        sums to C.
    """
    c, r = int(num_clusters), int(resamples)
    check_resamples(r, c)
    counts = np.zeros((r, c), dtype=np.int32)
    if c == 0 or r == 0:
        return counts
    # One bincount over the (row, cluster) pairs of a few rows at a time: the counted block
    # stays in cache (one bincount over all R×C cells scatters into ~R·C·8 bytes, 3× slower).
    rows = max(1, _CACHE_CELLS // c)
    for start in range(0, r, rows):
        m = min(rows, r - start)
        dtype = np.int32 if m * c < 2**31 else np.int64  # int32 draws are ~1.5x faster
        draws = rng.integers(0, c, size=(m, c), dtype=dtype)
        draws += (np.arange(m, dtype=dtype) * c)[:, None]
        counts[start : start + m] = np.bincount(draws.ravel(), minlength=m * c).reshape(m, c)
    return counts


def count_clusters(ids: np.ndarray) -> int:
    """The number of clusters of ids numbered 0..C-1 (:func:`cluster_ids`); 0 for no image."""
    ids = np.asarray(ids)
    return int(ids.max()) + 1 if ids.size else 0


def check_memory(nbytes: int, what: str) -> None:
    """Refuse, before allocating it, an array larger than the memory available now: the
    kernel's ``MemAvailable`` (free memory and the caches it can drop), not ``MemFree``, which
    reads far too low on a machine that has been reading files.

    Raises:
        ValueError: ``nbytes`` exceeds the memory available (a user's mistake, one line naming
            the size and the flag to lower, instead of a ``MemoryError`` traceback).
    """
    available = available_memory()
    if available is None:  # not Linux: let numpy decide
        return
    if nbytes > available:
        raise ValueError(
            f"{what} need {nbytes / 2**30:.1f} GiB and {available / 2**30:.1f} GiB are "
            "available: lower --bootstrap (1000 resamples is usual)"
        )


def bootstrap_bytes(resamples: int, num_clusters: int) -> int:
    """The most memory one interval of ``resamples`` resamples over ``num_clusters`` clusters
    holds at a time: its int32 draw counts and a few floats per resample."""
    return int(resamples) * (4 * int(num_clusters) + _BYTES_PER_RESAMPLE)


def check_resamples(resamples: int, num_clusters: int) -> None:
    """Refuse, before allocating anything, a bootstrap larger than the memory available now.

    Raises:
        ValueError: see :func:`check_memory`.
    """
    check_memory(
        bootstrap_bytes(resamples, num_clusters),
        f"{int(resamples)} resamples of {int(num_clusters)} clusters",
    )


def _local_clusters(clusters: np.ndarray, members: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Members' indices and their local cluster index 0..C-1 (sorted cluster-id order)."""
    members = np.asarray(members, dtype=np.int64).reshape(-1)
    labels = np.asarray(clusters)[members]
    _, local = np.unique(labels, return_inverse=True)
    return members, local.reshape(-1).astype(np.int64)


def set_clusters(
    clusters: np.ndarray,
    members: ArrayLike,
    settings: Bootstrap,
    counts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, int, str | None]:
    """A set's members, their local clusters (0..C-1), the number of clusters C, and why the set
    gets no interval (None: it gets one). Fixed ``counts`` (tests) need 2 clusters but no
    settings."""
    members, local = _local_clusters(clusters, members)
    num = count_clusters(local)
    note = _note(settings, num) if counts is None or num < 2 else None
    return members, local, num, note


def per_cluster_sums(rows: np.ndarray, local: np.ndarray, num_clusters: int) -> np.ndarray:
    """Sum of ``rows`` ([M, D]) per local cluster -> float64 [C, D] (sort + reduceat)."""
    order = np.argsort(local, kind="stable")
    sorted_local = local[order]
    starts = np.flatnonzero(np.r_[True, sorted_local[1:] != sorted_local[:-1]])
    out = np.add.reduceat(rows[order].astype(np.float64), starts, axis=0)
    assert out.shape[0] == num_clusters
    return out


def resampled(
    counts: np.ndarray, per_cluster: np.ndarray, statistic: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """``statistic(counts @ per_cluster)``, :data:`_CHUNK` resamples at a time: the resampled
    sums ([R, D] float64, D up to 6K) are never held whole, only the statistics ([R] or
    [R, S]) are."""
    out: np.ndarray | None = None
    for start in range(0, counts.shape[0], _CHUNK):
        block = counts[start : start + _CHUNK].astype(np.float64)
        values = np.asarray(statistic(block @ per_cluster), dtype=np.float64)
        if out is None:
            out = np.empty((counts.shape[0], *values.shape[1:]), dtype=np.float64)
        out[start : start + len(block)] = values
    return out if out is not None else np.empty(0, dtype=np.float64)


def confusion_features(confusions: np.ndarray) -> np.ndarray:
    """What mIoU and pixel accuracy need of each confusion [M,K,K]: float64 [M, 3K] =
    (true positives, ground-truth totals, predicted totals). Resampling these sums instead of
    the K×K cells is K/3 times less work and gives the same numbers (integer sums stay exact
    in float64 below 2^53 pixels)."""
    conf = np.asarray(confusions)
    tp = np.diagonal(conf, axis1=1, axis2=2)
    return np.concatenate([tp, conf.sum(axis=2), conf.sum(axis=1)], axis=1).astype(np.float64)


def _miou_acc(features: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
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


def percentile_interval(values: np.ndarray, level: float) -> list[float] | None:
    """The percentile interval of resampled values (NaN resamples left out); None if none."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(values, [alpha, 1.0 - alpha])
    return [float(lo), float(hi)]


def _note(settings: Bootstrap, num_clusters: int) -> str | None:
    """Why a set gets no interval (None: it gets one)."""
    if not settings.enabled:
        return "bootstrap off (--bootstrap 0)"
    if num_clusters < 2:
        return (
            f"{num_clusters} {settings.cluster} cluster{'s' if num_clusters != 1 else ''}: an "
            "interval needs at least 2 clusters to resample"
        )
    return None


def draws_for(
    num_clusters: int, settings: Bootstrap, counts: np.ndarray | None, stream: str
) -> np.ndarray:
    """The draw counts [R, C] of one set: ``counts`` when given (tests, checked), else drawn
    from the set's own generator ``stream``."""
    if counts is None:
        return draw_counts(num_clusters, settings.resamples, settings.rng(stream))
    counts = np.asarray(counts)
    if counts.ndim != 2 or counts.shape[1] != num_clusters:
        raise ValueError(f"draw counts {counts.shape} do not match {num_clusters} clusters")
    return counts


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
    both = resampled(draws, per_cluster, lambda sums: np.stack(_miou_acc(sums, k), axis=1))
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
    for start in range(0, draws.shape[0], _CHUNK):
        weights = draws[start : start + _CHUNK][:, local].astype(np.float64)
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
    return float(_miou_acc(confusion_features(summed), summed.shape[-1])[0][0])


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
        return _miou_acc(sums[:, 3 * k :], k)[0] - _miou_acc(sums[:, : 3 * k], k)[0]

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
            return _miou_acc(sums, k)[0]

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

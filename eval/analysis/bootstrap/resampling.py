"""The bootstrap's resampling: its settings (`Bootstrap`), the clusters of a set of images, the
draw counts of each set's own generator, the resampled sums as one matrix product per chunk,
the percentile interval, and the memory a run may take."""

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
CHUNK = 256
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
#: made and reduced :data:`CHUNK` resamples at a time, so they do not grow with R.
_BYTES_PER_RESAMPLE = 64


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
    """``statistic(counts @ per_cluster)``, :data:`CHUNK` resamples at a time: the resampled
    sums ([R, D] float64, D up to 6K) are never held whole, only the statistics ([R] or
    [R, S]) are."""
    out: np.ndarray | None = None
    for start in range(0, counts.shape[0], CHUNK):
        block = counts[start : start + CHUNK].astype(np.float64)
        values = np.asarray(statistic(block @ per_cluster), dtype=np.float64)
        if out is None:
            out = np.empty((counts.shape[0], *values.shape[1:]), dtype=np.float64)
        out[start : start + len(block)] = values
    return out if out is not None else np.empty(0, dtype=np.float64)


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

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

The steps live in three modules: :mod:`~claravid.eval.analysis.bootstrap.resampling` (settings,
clusters, draws, sums, the percentile interval), :mod:`~claravid.eval.analysis.bootstrap.intervals`
(mIoU, pixel accuracy, means, correlations) and
:mod:`~claravid.eval.analysis.bootstrap.gap_tests` (paired and unpaired gaps, p-values).
"""

from claravid.eval.analysis.bootstrap.gap_tests import p_value, paired_gap, unpaired_gap
from claravid.eval.analysis.bootstrap.intervals import (
    MIN_CORRELATION,
    confusion_features,
    confusion_interval,
    correlation_interval,
    mean_interval,
)
from claravid.eval.analysis.bootstrap.resampling import (
    METHOD,
    MIN_RESAMPLES,
    Bootstrap,
    bootstrap_bytes,
    check_memory,
    check_resamples,
    cluster_ids,
    count_clusters,
    draw_counts,
    draws_for,
    per_cluster_sums,
    percentile_interval,
    resampled,
    set_clusters,
)

__all__ = [
    "METHOD",
    "MIN_CORRELATION",
    "MIN_RESAMPLES",
    "Bootstrap",
    "bootstrap_bytes",
    "check_memory",
    "check_resamples",
    "cluster_ids",
    "confusion_features",
    "confusion_interval",
    "correlation_interval",
    "count_clusters",
    "draw_counts",
    "draws_for",
    "mean_interval",
    "p_value",
    "paired_gap",
    "per_cluster_sums",
    "percentile_interval",
    "resampled",
    "set_clusters",
    "unpaired_gap",
]

"""Cluster bootstrap (docs/evaluation.md): intervals checked against hand computations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    confusion_interval,
    correlation_interval,
    draw_counts,
    mean_interval,
    p_value,
    paired_gap,
    unpaired_gap,
)

# Three images, two clusters: images 0 and 1 in cluster "a", image 2 in cluster "b".
CONF = np.array(
    [
        [[3, 1], [0, 2]],
        [[1, 0], [1, 2]],
        [[0, 0], [2, 4]],
    ],
    dtype=np.int64,
)
LABELS = ["a", "a", "b"]
# Resample 1 draws cluster a twice, resample 2 cluster b twice, resample 3 each once.
DRAWS = np.array([[2, 0], [0, 2], [1, 1]])


def test_cluster_ids_follow_sorted_labels():
    assert cluster_ids(["m2", "m1", "m2", "m0"]).tolist() == [2, 1, 2, 0]
    assert cluster_ids([]).tolist() == []


def test_confusion_interval_by_hand():
    # By hand: cluster a sums to [[4,1],[1,4]] -> IoU 4/6, 4/6: mIoU 2/3, acc 8/10.
    # Cluster b [[0,0],[2,4]] -> IoU 0/2, 4/6: mIoU 1/3, acc 4/6. a+b = [[4,1],[3,8]] ->
    # IoU 4/8, 8/12: mIoU 7/12, acc 12/16. Resampled mIoU sorted: 1/3, 7/12, 2/3; the 50 %
    # interval is the 25th/75th percentile with linear interpolation (positions 0.5 and 1.5).
    out = confusion_interval(CONF, cluster_ids(LABELS), [0, 1, 2], Bootstrap(level=0.5), DRAWS)
    assert out["miou_ci"] == pytest.approx([11 / 24, 5 / 8])
    assert out["pixel_acc_ci"] == pytest.approx([17 / 24, 0.775])
    assert out["ci_note"] is None


def test_mean_interval_by_hand():
    # Values 1, 3 (cluster a: sum 4 over 2 images) and 10 (cluster b). Resampled means:
    # 8/4 = 2, 20/2 = 10, 14/3; interval at 50 %: 2 + (14/3 - 2)/2, 14/3 + (10 - 14/3)/2.
    values = np.array([1.0, 3.0, 10.0])
    out = mean_interval(values, cluster_ids(LABELS), [0, 1, 2], Bootstrap(level=0.5), DRAWS)
    assert out["mean"] == pytest.approx(14 / 3)
    assert out["ci"] == pytest.approx([10 / 3, 22 / 3])


def test_members_draw_only_their_own_clusters():
    # Members 1 and 2: cluster a holds only image 1 there ([[1,0],[1,2]]).
    labels = cluster_ids(["a", "a", "b"])
    draws = np.array([[2, 0], [0, 2]])
    out = confusion_interval(CONF, labels, [1, 2], Bootstrap(level=0.5), draws)
    # image 1 alone: IoU 1/2, 2/3 -> 7/12; image 2 alone: 1/3. Quantiles 0.25/0.75 of 2 values.
    lo, hi = 1 / 3, 7 / 12
    assert out["miou_ci"] == pytest.approx([lo + 0.25 * (hi - lo), lo + 0.75 * (hi - lo)])


def test_fewer_than_two_clusters_gives_a_note():
    out = confusion_interval(CONF, cluster_ids(["a", "a", "a"]), [0, 1, 2], Bootstrap())
    assert out["miou_ci"] is None and out["pixel_acc_ci"] is None
    assert "at least 2 clusters" in out["ci_note"]
    off = confusion_interval(CONF, cluster_ids(LABELS), [0, 1, 2], Bootstrap(resamples=0))
    assert off["miou_ci"] is None and "off" in off["ci_note"]


def test_draw_counts_rows_sum_to_clusters_and_repeat_with_seed():
    a = draw_counts(7, 500, np.random.default_rng(3))
    b = draw_counts(7, 500, np.random.default_rng(3))
    assert a.shape == (500, 7) and (a.sum(axis=1) == 7).all()
    np.testing.assert_array_equal(a, b)
    assert abs(a.mean() - 1.0) < 1e-12 and 0.8 < a.var() < 1.0  # multinomial var 1 - 1/C


def _random_confusions(n: int, k: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    conf = rng.integers(0, 40, size=(n, k, k))
    conf[:, np.arange(k), np.arange(k)] += rng.integers(50, 400, size=(n, k))
    return conf


def test_same_seed_same_numbers_and_streams_independent():
    conf = _random_confusions(30, 4, 0)
    ids = cluster_ids([str(i // 3) for i in range(30)])
    s = Bootstrap(resamples=200, seed=5)
    one = confusion_interval(conf, ids, range(30), s, stream="bin:low")
    assert one == confusion_interval(conf, ids, range(30), s, stream="bin:low")
    other = confusion_interval(conf, ids, range(30), Bootstrap(resamples=200, seed=6))
    assert one != other


def test_clusters_are_resampled_together():
    # Each image duplicated 4x inside its own viewpoint: resampling images treats the copies as
    # independent (too narrow); resampling viewpoints gives the interval of the set without
    # duplicates (the same draws over the same clusters; mIoU does not change when a confusion
    # is scaled by 4).
    base = _random_confusions(25, 3, 1)
    dup = np.repeat(base, 4, axis=0)
    viewpoints = [f"v{i // 4:02d}" for i in range(100)]
    settings = Bootstrap(resamples=2000, seed=0)
    by_image = confusion_interval(
        dup, cluster_ids([str(i) for i in range(100)]), range(100), settings
    )
    by_view = confusion_interval(dup, cluster_ids(viewpoints), range(100), settings)
    alone = confusion_interval(
        base, cluster_ids([f"v{i:02d}" for i in range(25)]), range(25), settings
    )
    width = lambda ci: ci[1] - ci[0]  # noqa: E731
    assert width(by_view["miou_ci"]) > 1.6 * width(by_image["miou_ci"])
    assert by_view["miou_ci"] == pytest.approx(alone["miou_ci"], rel=1e-9)


def test_correlation_interval_matches_scipy_on_the_resampled_multiset():
    rng = np.random.default_rng(2)
    x = rng.normal(size=12)
    y = x + rng.normal(size=12)
    y[4] = y[5]  # ties for Spearman
    labels = [f"c{i // 2}" for i in range(12)]  # 6 clusters of 2 images
    draws = np.array([[2, 0, 1, 1, 0, 2], [1, 1, 1, 1, 1, 1], [0, 3, 0, 1, 2, 0]])
    ids = cluster_ids(labels)
    expected_p, expected_s = [], []
    for row in draws:
        take = np.repeat(np.arange(12), row[ids])  # each image as often as its cluster
        expected_p.append(stats.pearsonr(x[take], y[take]).statistic)
        expected_s.append(stats.spearmanr(x[take], y[take]).statistic)
    out = correlation_interval(x, y, ids, Bootstrap(level=0.5), draws)
    assert out["pearson_ci"] == pytest.approx(np.quantile(expected_p, [0.25, 0.75]).tolist())
    assert out["spearman_ci"] == pytest.approx(np.quantile(expected_s, [0.25, 0.75]).tolist())


def test_paired_gap_of_identical_predictions_is_exactly_zero():
    conf = _random_confusions(40, 5, 3)
    ids = cluster_ids([str(i // 4) for i in range(40)])
    out = paired_gap(conf, conf.copy(), ids, range(40), Bootstrap(resamples=300))
    assert out["gap"] == 0.0 and out["gap_ci"] == [0.0, 0.0] and out["p_value"] == 1.0


def test_injected_error_is_significant():
    # B moves 10 % of every image's class-0 pixels to class 1: worse on every image.
    a = _random_confusions(40, 3, 4)
    b = a.copy()
    moved = a[:, 0, 0] // 10
    b[:, 0, 0] -= moved
    b[:, 0, 1] += moved
    ids = cluster_ids([str(i // 4) for i in range(40)])
    out = paired_gap(a, b, ids, range(40), Bootstrap(resamples=500))
    assert out["gap"] < 0 and out["gap_ci"][1] < 0 and out["p_value"] < 0.01
    unpaired = unpaired_gap(a, ids, range(40), b, ids, range(40), Bootstrap(resamples=500))
    assert unpaired["gap"] == pytest.approx(out["gap"])
    # Without pairing the between-image spread enters: a wider interval.
    assert unpaired["gap_ci"][1] - unpaired["gap_ci"][0] > out["gap_ci"][1] - out["gap_ci"][0]


def test_p_value_by_hand():
    gaps = np.array([0.3, 0.2, -0.1, 0.1, 0.0])  # 2 of 5 at or below 0
    assert p_value(gaps, 0.2) == pytest.approx(0.8)
    assert p_value(gaps, -0.1) == pytest.approx(1.0)  # 4 of 5 at or above 0 -> min(1, 1.6)
    assert p_value(np.zeros(4), 0.0) == 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"resamples": -1}, ">= 0"),
        ({"level": 1.5}, "between 0 and 1"),
        ({"level": 0.0}, "between 0 and 1"),
        ({"cluster": "tile"}, "unknown --cluster 'tile'"),
        ({"seed": -2}, "seed"),
    ],
)
def test_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Bootstrap(**kwargs)


def test_the_seed_alone_changes_the_draws():
    # One stream, two seeds: only the seed differs (a generator seeded with a constant would
    # give the same draws). And the generator is the documented one: default_rng([seed,
    # crc32(stream)]).
    import zlib

    conf = _random_confusions(30, 4, 0)
    ids = cluster_ids([str(i // 3) for i in range(30)])
    five = confusion_interval(conf, ids, range(30), Bootstrap(resamples=200, seed=5), stream="x")
    six = confusion_interval(conf, ids, range(30), Bootstrap(resamples=200, seed=6), stream="x")
    assert five["miou_ci"] != six["miou_ci"]
    expected = np.random.default_rng([6, zlib.crc32(b"x")]).integers(0, 1000, 8)
    np.testing.assert_array_equal(Bootstrap(seed=6).rng("x").integers(0, 1000, 8), expected)


def test_mean_interval_leaves_out_non_finite_values():
    # test_mean_interval_by_hand's values with a NaN and an inf added to cluster a: the same
    # mean and interval as without them.
    values = np.array([1.0, np.nan, 3.0, np.inf, 10.0])
    clusters = cluster_ids(["a", "a", "a", "a", "b"])
    out = mean_interval(values, clusters, range(5), Bootstrap(level=0.5), DRAWS)
    assert out["mean"] == pytest.approx(14 / 3)
    assert out["ci"] == pytest.approx([10 / 3, 22 / 3])


def test_a_correlation_interval_needs_four_pairs_and_four_clusters():
    # 3 images: every resample with all three gives the same r, a zero-width "interval".
    x, y = np.array([1.0, 2.0, 4.0]), np.array([1.0, 3.0, 2.0])
    out = correlation_interval(x, y, cluster_ids(["a", "b", "c"]), Bootstrap(resamples=200))
    assert out["pearson_ci"] is None and out["spearman_ci"] is None
    assert "3 image pairs in 3 image clusters" in out["ci_note"] and "at least 4" in out["ci_note"]
    # 8 images in 3 clusters: still too few clusters to resample.
    x8 = np.arange(8.0)
    out = correlation_interval(x8, x8**2, cluster_ids(list("aaabbbcc")), Bootstrap(resamples=200))
    assert out["pearson_ci"] is None and "in 3 image clusters" in out["ci_note"]
    ids = cluster_ids(list("aabbccdd"))
    four = correlation_interval(x8, x8**2, ids, Bootstrap(resamples=200))
    assert four["ci_note"] is None
    # The interval restated from the same draws (the set's documented generator), with scipy;
    # resamples of one cluster (2 distinct pairs) have no r and are left out.
    draws = draw_counts(4, 200, Bootstrap().rng(""))
    rs = []
    for row in draws:
        take = np.repeat(np.arange(8), row[ids])
        if len(set(take.tolist())) >= 3:
            rs.append(stats.pearsonr(x8[take], x8[take] ** 2).statistic)
    assert four["pearson_ci"] == pytest.approx(np.quantile(rs, [0.025, 0.975]).tolist())


@pytest.mark.parametrize("resamples", [1, 2, 5, 99])
def test_too_few_resamples_are_refused(resamples):
    with pytest.raises(ValueError, match=f"{resamples} is too few .* at least 100"):
        Bootstrap(resamples=resamples)
    assert Bootstrap(resamples=100).enabled and not Bootstrap(resamples=0).enabled


def test_a_bootstrap_larger_than_memory_is_refused_before_allocating():
    # 10^9 resamples of 1000 clusters: 4 bytes of draw count per cluster and at most 64 bytes
    # of statistics per resample, 10^9 x 4064 bytes = 3784.9 GiB.
    with pytest.raises(ValueError, match=r"need 3784\.9 GiB .* lower --bootstrap"):
        draw_counts(1000, 10**9, np.random.default_rng(0))


def test_non_finite_resamples_are_dropped_before_the_percentiles():
    """Resamples whose statistic is undefined (one cluster of 2 pairs: no correlation; only
    images without a labelled pixel: no mIoU) are left out, and the interval is the percentile
    interval of the others, restated with scipy and numpy (an interval of [nan, nan] fails)."""
    x = np.arange(8.0)
    y = np.array([0.0, 3.0, 1.0, 5.0, 4.0, 2.0, 7.0, 6.0])
    ids = cluster_ids(list("aabbccdd"))
    draws = np.array([[4, 0, 0, 0], [1, 1, 1, 1], [0, 0, 0, 4], [2, 0, 1, 1], [0, 2, 2, 0],
                      [1, 3, 0, 0]])  # fmt: skip
    defined = []
    for row in draws:
        take = np.repeat(np.arange(8), row[ids])
        if len(set(take.tolist())) >= 3:  # rows 0 and 2 hold one cluster: 2 distinct pairs
            defined.append(stats.pearsonr(x[take], y[take]).statistic)
    assert len(defined) == 4
    out = correlation_interval(x, y, ids, Bootstrap(level=0.5), draws)
    assert out["pearson_ci"] == pytest.approx(np.quantile(defined, [0.25, 0.75]).tolist())
    # Confusions: cluster "b" (image 2) has no labelled pixel, so a resample of b alone has
    # no mIoU; the others are counted by hand.
    conf = np.array([[[3, 1], [0, 2]], [[1, 0], [1, 2]], [[0, 0], [0, 0]]], dtype=np.int64)
    draws2 = np.array([[0, 2], [2, 0], [1, 1], [0, 2]])
    miou = []
    for row in draws2:
        summed = row[0] * conf[:2].sum(0) + row[1] * conf[2]
        tp = np.diag(summed)
        union = summed.sum(0) + summed.sum(1) - tp
        if (union > 0).any():
            miou.append((tp[union > 0] / union[union > 0]).mean())
    assert len(miou) == 2
    out = confusion_interval(conf, cluster_ids(["a", "a", "b"]), range(3), Bootstrap(level=0.5),
                             draws2)  # fmt: skip
    assert out["miou_ci"] == pytest.approx(np.quantile(miou, [0.25, 0.75]).tolist())
    gap = paired_gap(conf, conf, cluster_ids(["a", "a", "b"]), range(3), Bootstrap(level=0.5),
                     draws2)  # fmt: skip
    assert gap["gap_ci"] == [0.0, 0.0]  # the two undefined gaps left out, not [nan, nan]

"""The measures beyond mIoU as statistics of summed per-image rows, checked by hand: mBoundaryIoU,
ECE/MCE, cross-view consistency, their bootstrap intervals and paired gaps."""

from __future__ import annotations

import numpy as np
import pytest

from claravid.eval.analysis.bootstrap import Bootstrap, cluster_ids
from claravid.eval.analysis.quality import (
    boundary_stat,
    calibration_stat,
    consistency_stat,
    image_values,
    quality_entries,
)
from claravid.eval.analysis.quality_table import (
    ABSENT,
    COMPUTED,
    PAIR_LAST,
    PAIR_OK,
    PAIR_TURN,
    UNAVAILABLE,
    PairTable,
    QualityTable,
    concat_quality,
)
from claravid.eval.analysis.sum_intervals import (
    paired_sums_gap,
    sums_interval,
    unpaired_sums_gap,
)

CLASSES = ["a", "b"]
# Boundary sums of three images, K = 2: [intersections, unions].
BOUNDARY = np.array([[[3, 0], [4, 0]], [[1, 2], [2, 4]], [[0, 1], [0, 3]]], dtype=np.int64)
LABELS = ["x", "x", "y"]  # images 0 and 1 in cluster x, image 2 in cluster y
DRAWS = np.array([[2, 0], [0, 2], [1, 1]])


def test_boundary_miou_by_hand():
    # All three: class a 4/6, class b 3/7 -> (4/6 + 3/7) / 2; class b absent from image 0 (union
    # 0) leaves image 0's own value at class a alone: 3/4.
    rows = BOUNDARY.reshape(3, -1).astype(float)
    assert boundary_stat(rows.sum(0, keepdims=True))[0, 0] == pytest.approx((4 / 6 + 3 / 7) / 2)
    assert boundary_stat(rows)[:, 0] == pytest.approx([3 / 4, (1 / 2 + 2 / 4) / 2, 1 / 3])
    empty = boundary_stat(np.zeros((1, 4)))
    assert np.isnan(empty[0, 0])


def test_ece_and_mce_by_hand_equal_the_pixel_definition():
    # Six pixels with confidences and correctness; 3 bins (0, 1/3], (1/3, 2/3], (2/3, 1].
    conf = np.array([0.2, 0.5, 0.6, 0.9, 0.95, 1.0])
    correct = np.array([0, 1, 0, 1, 1, 0])
    edges = np.array([0, 1 / 3, 2 / 3, 1])
    bins = np.searchsorted(edges[1:-1], conf, side="left")  # (lo, hi]
    count = np.bincount(bins, minlength=3)
    sums = np.concatenate([count, np.bincount(bins, conf, 3), np.bincount(bins, correct, 3)])
    ece, mce = calibration_stat(sums[None].astype(float))[0]
    # By the definition: sum over bins of n_b/N |acc_b - conf_b|.
    by_bin = [abs(correct[bins == b].mean() - conf[bins == b].mean()) for b in range(3)]
    want = sum(count[b] / 6 * by_bin[b] for b in range(3))
    assert ece == pytest.approx(want)
    assert ece == pytest.approx((0.2 + abs(1 - 1.1) + abs(2 - 2.85)) / 6)
    assert mce == pytest.approx(max(by_bin))
    # An empty bin does not count towards MCE (count 0 in the middle bin).
    sums2 = np.array([[2, 0, 1, 1.0, 0, 0.9, 2, 0, 0]])
    assert calibration_stat(sums2)[0, 1] == pytest.approx(0.9)


def test_consistency_by_hand():
    # kept, agree, agree_gt, then K=2: inter, union (pred), inter, union (GT).
    rows = np.array(
        [[10, 8, 10, 5, 3, 6, 4, 4, 4, 5, 5], [10, 5, 9, 2, 1, 4, 6, 5, 4, 6, 4]], dtype=float
    )
    agreement, tc, agreement_gt, tc_gt = consistency_stat(rows.sum(0, keepdims=True))[0]
    assert agreement == pytest.approx(13 / 20)
    assert agreement_gt == pytest.approx(19 / 20)
    assert tc == pytest.approx((7 / 10 + 4 / 10) / 2)
    assert tc_gt == pytest.approx((9 / 11 + 8 / 9) / 2)
    assert np.isnan(consistency_stat(np.zeros((1, 11)))).all()


def test_sums_interval_by_hand():
    # Cluster x sums: a 4/6, b 2/4 -> 7/12; cluster y: b 1/3 -> 1/3; both: (4/6 + 3/7)/2.
    rows = BOUNDARY.reshape(3, -1)
    out = sums_interval(rows, cluster_ids(LABELS), [0, 1, 2], Bootstrap(level=0.5),
                        boundary_stat, ["miou"], counts=DRAWS)  # fmt: skip
    both = (4 / 6 + 3 / 7) / 2
    values = sorted([7 / 12, 1 / 3, both])
    lo = values[0] + 0.5 * (values[1] - values[0])
    hi = values[1] + 0.5 * (values[2] - values[1])
    assert out["miou_ci"] == pytest.approx([lo, hi])
    assert out["ci_note"] is None
    one = sums_interval(rows, cluster_ids(LABELS), [0, 1], Bootstrap(), boundary_stat, ["miou"])
    assert one["miou_ci"] is None and "1 image cluster" in one["ci_note"]


def test_paired_gap_by_hand_and_unpaired_keeps_its_own_draws():
    a = BOUNDARY.reshape(3, -1)
    b = a.copy()
    b[2] = [0, 3, 0, 3]  # image 2 of B gets class b's boundary right: 3/3
    out = paired_sums_gap(a, b, cluster_ids(LABELS), [0, 1, 2], Bootstrap(level=0.5),
                          boundary_stat, ["miou"], counts=DRAWS)["miou"]  # fmt: skip
    gap_all = (4 / 6 + 5 / 7) / 2 - (4 / 6 + 3 / 7) / 2
    assert out["gap"] == pytest.approx(gap_all)
    # Resamples: x twice (no change: 0), y twice (1 - 1/3), both (gap_all).
    gaps = sorted([0.0, 2 / 3, gap_all])
    assert out["gap_ci"] == pytest.approx(
        [gaps[0] + 0.5 * (gaps[1] - gaps[0]), gaps[1] + 0.5 * (gaps[2] - gaps[1])]
    )
    assert out["paired"] is True and out["p_value"] == pytest.approx(2 / 3)
    ids = cluster_ids(LABELS)
    unpaired = unpaired_sums_gap(a, ids, [0, 1, 2], b, ids, [0, 1, 2],
                                 Bootstrap(resamples=200), boundary_stat, ["miou"])  # fmt: skip
    assert unpaired["miou"]["gap"] == pytest.approx(gap_all)
    assert unpaired["miou"]["paired"] is False and unpaired["miou"]["gap_ci"] is not None


def _pairs(n: int, k: int = 2) -> PairTable:
    sums = np.zeros((n, 3 + 4 * k), dtype=np.int64)
    sums[0] = [10, 8, 10, 5, 3, 6, 4, 4, 4, 5, 5]
    return PairTable(
        [f"f{i + 1}" for i in range(n - 1)] + [""],
        [PAIR_OK] + [PAIR_TURN] * (n - 2) + [PAIR_LAST],
        [""] * n,
        sums,
    )


def test_entries_carry_statistics_intervals_and_counts():
    calibration = np.zeros((3, 3, 2))
    calibration[:, 0] = [[2, 2], [1, 0], [0, 4]]  # counts per bin
    calibration[:, 1] = [[0.4, 1.6], [0.3, 0], [0, 3.6]]  # confidence sums
    calibration[:, 2] = [[1, 2], [0, 0], [0, 3]]  # correct
    table = QualityTable({"boundary_iou": COMPUTED, "calibration": COMPUTED,
                          "consistency": COMPUTED}, boundary=BOUNDARY, calibration=calibration,
                         pairs=_pairs(3))  # fmt: skip
    out = quality_entries(table, [0, 1, 2], CLASSES, clusters=cluster_ids(LABELS),
                          bootstrap=Bootstrap(resamples=100))  # fmt: skip
    assert out["boundary_iou"]["miou"] == pytest.approx((4 / 6 + 3 / 7) / 2)
    assert out["boundary_iou"]["per_class_iou"] == pytest.approx({"a": 4 / 6, "b": 3 / 7})
    cal = out["calibration"]
    # Bin 0: 3 pixels, confidence 0.7, correct 1; bin 1: 6 pixels, confidence 5.2, correct 5.
    assert cal["ece"] == pytest.approx((abs(1 - 0.7) + abs(5 - 5.2)) / 9)
    assert cal["mce"] == pytest.approx(0.1)
    assert cal["num_pixels"] == 9 and cal["reliability"]["count"] == [3, 6]
    assert cal["reliability"]["accuracy"] == pytest.approx([1 / 3, 5 / 6])
    assert cal["ece_ci"] is not None and cal["mce_ci"] is not None
    con = out["consistency"]
    assert con["agreement"] == pytest.approx(0.8) and con["agreement_gt"] == pytest.approx(1.0)
    assert con["pairs"]["ok"] == 1 and con["pairs"]["turn"] == 1 and con["pairs"]["last"] == 1
    assert con["kept_pixels"] == 10
    values = image_values(table)
    assert values["consistency"][0] == pytest.approx(0.8) and np.isnan(values["consistency"][1])
    assert values["ece"][2] == pytest.approx(0.6 / 4)


def test_concat_keeps_a_measure_only_when_every_part_has_it():
    a = QualityTable({"boundary_iou": COMPUTED}, boundary=BOUNDARY[:2], pairs=None)
    b = QualityTable({"boundary_iou": COMPUTED}, boundary=BOUNDARY[2:])
    old = QualityTable.absent("written before")
    joined = concat_quality([a, b], ["p0", "p1"], np.array([2, 0, 1]))
    assert joined.status["boundary_iou"] == COMPUTED
    np.testing.assert_array_equal(joined.boundary, BOUNDARY[[2, 0, 1]])
    assert joined.status["calibration"] == ABSENT
    mixed = concat_quality([a, old], ["p0", "old"], np.array([0, 1, 2, 3])[:2])
    assert mixed.status["boundary_iou"] == UNAVAILABLE
    assert "old (absent)" in mixed.reasons["boundary_iou"]
    other = QualityTable({"boundary_iou": COMPUTED}, boundary=BOUNDARY[2:],
                         settings={"boundary_iou": {"dilation_ratio": 0.05}})  # fmt: skip
    assert concat_quality([a, other], ["p0", "p1"], np.arange(3)).status["boundary_iou"] == (
        UNAVAILABLE
    )


def test_status_must_match_the_sums():
    with pytest.raises(ValueError, match="boundary_iou is computed but its sums are missing"):
        QualityTable({"boundary_iou": COMPUTED})
    with pytest.raises(ValueError, match="unknown pair status"):
        PairTable(["x"], ["done"], [""], np.zeros((1, 11), np.int64))

"""Per-bin, per-group and per-image scores and correlations against hand-computed values."""

import numpy as np
import pytest
from scipy import stats

from claravid.eval.analysis.miou_bins import bin_mious, stratify
from claravid.eval.analysis.stats import correlation

CLASSES = ["a", "b"]
PATHS = ["p/a.jpg", "p/b.jpg", "p/c.jpg", "p/d.jpg"]
CONFUSIONS = np.array(
    [
        [[2, 0], [0, 2]],  # mIoU 1
        [[1, 1], [0, 2]],  # IoU 1/2, 2/3 -> 7/12
        [[0, 2], [0, 0]],  # IoU 0, 0 -> 0
        [[0, 0], [2, 2]],  # IoU 0, 1/2 -> 1/4
    ]
)
DELENT = [1.0, 2.0, 3.0, 4.0]


def test_bins_use_the_summed_confusion_not_the_mean_of_images():
    report = stratify(PATHS, CONFUSIONS, CLASSES, {"delent": DELENT}, bins=2)
    low, high = report["bins"]
    # low = a + b = [[3,1],[0,4]]: IoU 3/4 and 4/5; the mean of the images' mIoUs would be 0.79.
    assert low["name"] == "low" and low["num_images"] == 2
    assert low["miou"] == pytest.approx((3 / 4 + 4 / 5) / 2)
    assert low["per_class_iou"] == {"a": pytest.approx(0.75), "b": pytest.approx(0.8)}
    assert (low["lo"], low["hi"]) == (1.0, 2.0)
    # high = c + d = [[0,2],[2,2]]: IoU 0 and 2/6.
    assert high["miou"] == pytest.approx((0 + 1 / 3) / 2)
    assert high["pixel_acc"] == pytest.approx(2 / 6)
    assert bin_mious(report) == {"low": low["miou"], "high": high["miou"]}


def test_overall_images_and_correlation_by_hand():
    report = stratify(PATHS, CONFUSIONS, CLASSES, {"delent": DELENT}, bins=2)
    overall = report["overall"]  # [[3,3],[2,6]]
    assert overall["miou"] == pytest.approx((3 / 8 + 6 / 11) / 2)
    assert overall["pixel_acc"] == pytest.approx(9 / 14)
    assert overall["num_images"] == 4
    mious = [row["miou"] for row in report["images"]]
    assert mious == pytest.approx([1, 7 / 12, 0, 1 / 4])
    assert report["images"][1] == {
        "path": "p/b.jpg", "delent": 2.0, "miou": pytest.approx(7 / 12), "pixel_acc": 0.75,
    }  # fmt: skip
    corr = report["correlation"]["delent"]
    assert corr["n"] == 4
    assert corr["spearman"] == pytest.approx(-0.8)  # ranks 4,3,1,2 vs 1,2,3,4
    assert corr["pearson"] == pytest.approx(stats.pearsonr(DELENT, mious).statistic)
    assert report["ignore_index"] == 255 and "summed confusion" in report["convention"]


def test_groups_carry_their_profile():
    report = stratify(
        PATHS, CONFUSIONS, CLASSES, {"delent": DELENT}, groups={"m1": [0, 2], "m2": [1, 3]}
    )
    m1 = report["groups"][0]
    assert m1["name"] == "m1" and m1["num_images"] == 2
    assert m1["miou"] == pytest.approx((2 / 4 + 2 / 4) / 2)  # [[2,2],[0,2]]
    assert m1["profile"]["mu"] == pytest.approx(2.0)
    assert m1["profile"]["sigma"] == pytest.approx(1.0)


def test_fixed_edges_keep_empty_bins_and_list_outsiders():
    report = stratify(PATHS, CONFUSIONS, CLASSES, {"delent": DELENT}, edges=[0.0, 2.0, 3.5, 9.0])
    assert [b["num_images"] for b in report["bins"]] == [1, 2, 1]
    report = stratify(PATHS, CONFUSIONS, CLASSES, {"delent": DELENT}, edges=[1.5, 2.5, 10, 20])
    rows = report["bins"]
    assert [b["num_images"] for b in rows] == [1, 2, 0]
    assert rows[2]["miou"] is None and (rows[2]["lo"], rows[2]["hi"]) == (10, 20)
    assert report["binning"]["outside"] == ["p/a.jpg"]


def test_images_without_valid_pixels_are_left_out_of_correlations():
    confusions = np.concatenate([CONFUSIONS, np.zeros((1, 2, 2), dtype=np.int64)])
    report = stratify([*PATHS, "p/e.jpg"], confusions, CLASSES, {"delent": [*DELENT, 5.0]})
    assert report["images"][-1]["miou"] is None
    assert report["correlation"]["delent"]["n"] == 4


def test_degenerate_correlations_are_null():
    assert correlation([1, 2], [3, 4]) == {"pearson": None, "spearman": None, "n": 2}
    assert correlation([1, 1, 1], [3, 4, 5])["pearson"] is None


def test_mismatched_inputs():
    with pytest.raises(ValueError, match="do not match"):
        stratify(PATHS[:3], CONFUSIONS, CLASSES)
    with pytest.raises(ValueError, match="3 delent values for 4 images"):
        stratify(PATHS, CONFUSIONS, CLASSES, {"delent": DELENT[:3]})

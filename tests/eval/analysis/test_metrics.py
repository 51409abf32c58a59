"""IoU, mIoU and pixel accuracy of a confusion matrix against hand-computed values."""

import math

import numpy as np
import pytest

from claravid.eval.analysis.metrics import confusion_scores, iou_per_class, mean_iou, pixel_accuracy

# Rows = truth, columns = prediction, counted by hand from 7 valid pixels of 3 classes.
HAND = np.array([[1, 1, 0], [0, 2, 1], [1, 0, 1]])


def test_iou_miou_accuracy_by_hand():
    # class 0: TP 1, FP 1 (truth 2 -> 0), FN 1 -> 1/3; class 1: TP 2, FP 1, FN 1 -> 2/4;
    # class 2: TP 1, FP 1, FN 1 -> 1/3.
    np.testing.assert_allclose(iou_per_class(HAND), [1 / 3, 1 / 2, 1 / 3])
    assert mean_iou(HAND) == pytest.approx((1 / 3 + 1 / 2 + 1 / 3) / 3)
    assert pixel_accuracy(HAND) == pytest.approx(4 / 7)


def test_a_class_with_no_pixels_is_left_out_of_the_mean():
    conf = np.array([[3, 1, 0], [0, 0, 0], [0, 0, 0]])  # class 2 absent everywhere
    iou = iou_per_class(conf)
    assert iou[0] == pytest.approx(3 / 4)
    assert iou[1] == 0.0  # predicted but never true: union 1, a real 0
    assert math.isnan(iou[2])
    assert mean_iou(conf) == pytest.approx((3 / 4 + 0) / 2)
    out = confusion_scores(conf, ["a", "b", "c"])
    assert out["per_class_iou"] == {"a": 0.75, "b": 0.0, "c": None}

"""Confusion matrices (and the scores of an empty one) against hand-computed values."""

import math

import numpy as np
import pytest
import torch

from claravid.eval.analysis.metrics import confusion_scores, mean_iou, pixel_accuracy
from claravid.eval.measures.confusion import confusion_matrix

# 3 classes, one ignored pixel (255). Truth row by row, prediction below it.
TRUTH = np.array([[0, 0, 1, 1], [1, 2, 2, 255]])
PRED = np.array([[0, 1, 1, 1], [2, 2, 0, 0]])
# Counted by hand, rows = truth, columns = prediction (the 255 pixel is skipped):
#   truth 0: pred 0, pred 1        -> [1, 1, 0]
#   truth 1: pred 1, pred 1, pred 2 -> [0, 2, 1]
#   truth 2: pred 2, pred 0        -> [1, 0, 1]
HAND = np.array([[1, 1, 0], [0, 2, 1], [1, 0, 1]])


def test_confusion_by_hand():
    conf = confusion_matrix(PRED, TRUTH, 3)
    assert conf.dtype == torch.int64
    np.testing.assert_array_equal(conf.numpy(), HAND)


def test_nothing_valid_gives_nan_not_zero():
    conf = confusion_matrix(np.zeros((2, 2)), np.full((2, 2), 255), 3)
    assert conf.sum() == 0
    assert math.isnan(mean_iou(conf)) and math.isnan(pixel_accuracy(conf))
    assert confusion_scores(conf, "abc")["miou"] is None


def test_out_of_palette_ids_are_an_error():
    with pytest.raises(ValueError, match=r"prediction holds ids \[3\]"):
        confusion_matrix(np.array([3]), np.array([0]), 3)
    with pytest.raises(ValueError, match="ground truth holds ids"):
        confusion_matrix(np.array([0]), np.array([7]), 3)
    with pytest.raises(ValueError, match="differ in shape"):
        confusion_matrix(np.zeros((2, 3)), np.zeros((3, 2)), 3)


@pytest.mark.parametrize("num_classes", [3, 19, 200])
def test_cpu_fast_path_counts_like_a_direct_count(num_classes):
    # uint8 arrays take the OpenCV path, int64 tensors the bincount path: both must equal a
    # count made with np.add.at, including junk predictions under ignored pixels.
    rng = np.random.default_rng(num_classes)
    truth = rng.integers(0, num_classes, (37, 53))
    truth[rng.random(truth.shape) < 0.2] = 255
    pred = rng.integers(0, num_classes, truth.shape)
    pred[(truth == 255) & (rng.random(truth.shape) < 0.5)] = 250
    expected = np.zeros((num_classes, num_classes), dtype=np.int64)
    valid = truth != 255
    np.add.at(expected, (truth[valid], pred[valid]), 1)
    fast = confusion_matrix(pred.astype(np.uint8), truth.astype(np.uint8), num_classes)
    slow = confusion_matrix(torch.from_numpy(pred), torch.from_numpy(truth), num_classes)
    np.testing.assert_array_equal(fast.numpy(), expected)
    np.testing.assert_array_equal(slow.numpy(), expected)


def test_cpu_fast_path_reports_out_of_palette_ids():
    truth = np.array([[0, 255, 1]], dtype=np.uint8)
    with pytest.raises(ValueError, match=r"prediction holds ids \[4\]"):
        confusion_matrix(np.array([[4, 9, 0]], dtype=np.uint8), truth, 3)
    with pytest.raises(ValueError, match=r"ground truth holds ids \[3\]"):
        confusion_matrix(np.zeros((1, 3), np.uint8), np.array([[3, 0, 0]], np.uint8), 3)

"""Boundary IoU against the plain definition (iterated 3×3 erosions, tests/helpers/scoring.py)
and a hand-counted case."""

import numpy as np
import pytest
import torch

from claravid.eval.measures.boundary import boundary_iou, boundary_width
from tests.helpers.scoring import boundary_iou_by_hand


def blobs(rng, shape, num_classes, count=12):
    """A label image of overlapping random rectangles and discs (shapes a segmenter outputs)."""
    height, width = shape
    out = np.full(shape, rng.integers(num_classes), np.uint8)
    yy, xx = np.mgrid[:height, :width]
    for _ in range(count):
        c = rng.integers(num_classes)
        y, x = rng.integers(height), rng.integers(width)
        if rng.random() < 0.5:
            r = rng.integers(1, max(2, min(shape) // 3))
            out[(yy - y) ** 2 + (xx - x) ** 2 <= r * r] = c
        else:
            out[y : y + rng.integers(1, height + 1), x : x + rng.integers(1, width + 1)] = c
    return out


def test_hand_counted_shift_by_one_column():
    """6×8, d = 1: the truth splits at column 4, the prediction at 5 (counted in comments)."""
    gt = np.zeros((6, 8), np.uint8)
    gt[:, 4:] = 1
    pred = np.zeros((6, 8), np.uint8)
    pred[:, 5:] = 1
    # G0: columns 0 and 3, rows 0 and 5 at columns 1-2 (16). P0: columns 0 and 4, rows 0 and 5
    # at columns 1-3 (18). Shared: column 0, rows 0/5 at columns 1-3 (6 + 6) = 12.
    # G1: columns 4 and 7, rows 0/5 at columns 5-6 (16). P1: columns 5 and 7, rows 0/5 at
    # column 6 (14). Shared: column 7, rows 0/5 at columns 5-6 (6 + 4) = 10.
    inter, union = boundary_iou(pred, gt, 2)
    assert boundary_width(gt.shape) == 1  # round(0.02 · 10) = 0 -> at least 1
    assert inter.dtype == np.int64 and union.dtype == np.int64
    np.testing.assert_array_equal(inter, [12, 10])
    np.testing.assert_array_equal(union, [16 + 18 - 12, 16 + 14 - 10])


def test_hand_counted_ignore_region():
    """An ignored pixel is not class 0: its neighbours become boundary; it counts for nothing."""
    gt = np.zeros((5, 5), np.uint8)
    gt[2, 2] = 255
    pred = np.zeros((5, 5), np.uint8)
    # d = 1. G0 = the border ring (16) + the 8 pixels around the centre = 24 (the centre itself
    # is ignored). P0 = the ring (16); the prediction's centre is class 0 but interior.
    inter, union = boundary_iou(pred, gt, 1)
    np.testing.assert_array_equal(inter, [16])
    np.testing.assert_array_equal(union, [24])


@pytest.mark.parametrize(
    ("shape", "num_classes", "ratio"),
    [
        ((37, 53), 4, 0.02),  # d = 1
        ((48, 64), 6, 0.06),  # d = 5, non-square
        ((61, 29), 3, 0.15),  # d = 10, taller than wide
        ((40, 40), 5, 0.5),  # d = 28: wider than half the image, everything is boundary
        ((1, 50), 2, 0.02),  # one row
        ((50, 1), 2, 0.1),  # one column
    ],
)
def test_random_masks_match_the_iterated_erosions(shape, num_classes, ratio):
    rng = np.random.default_rng(sum(shape) + num_classes)
    for _ in range(4):
        gt = blobs(rng, shape, num_classes)
        pred = blobs(rng, shape, num_classes)
        gt[rng.random(shape) < 0.05] = 255  # scattered ignored pixels
        gt[: shape[0] // 4, : shape[1] // 3] = 255  # and an ignored region touching the border
        pred[gt == 255] = rng.integers(0, 256, int((gt == 255).sum()))  # junk where ignored
        inter, union = boundary_iou(pred, gt, num_classes, dilation_ratio=ratio)
        ref_inter, ref_union = boundary_iou_by_hand(pred, gt, num_classes, ratio)
        np.testing.assert_array_equal(inter, ref_inter)
        np.testing.assert_array_equal(union, ref_union)


def test_hand_drawn_masks_with_border_cases():
    """Thin lines, a lone pixel, classes on the border and an absent class (union 0)."""
    gt = np.full((20, 30), 2, np.uint8)
    gt[:, :3] = 0  # a strip along the left border
    gt[5, 4:26] = 1  # a one-pixel-wide line (a wire)
    gt[12, 15] = 1  # a lone pixel
    gt[15:, 20:] = 3  # a block in the bottom-right corner
    pred = gt.copy()
    pred[5, 4:26] = 2  # the wire missed
    pred[14:, 19:] = 3  # the block grown by one pixel
    pred[0, :] = 0  # a wrong first row
    for ratio in (0.02, 0.1, 0.3):
        inter, union = boundary_iou(pred, gt, 5, dilation_ratio=ratio)
        ref_inter, ref_union = boundary_iou_by_hand(pred, gt, 5, ratio)
        np.testing.assert_array_equal(inter, ref_inter)
        np.testing.assert_array_equal(union, ref_union)
        assert union[4] == 0  # class 4 is nowhere: left out of a group's mean


def test_one_class_everywhere_is_a_band_along_the_border():
    gt = np.zeros((30, 40), np.uint8)
    d = boundary_width(gt.shape, 0.1)  # round(0.1 · 50) = 5
    inter, union = boundary_iou(gt, gt, 1, dilation_ratio=0.1)
    assert d == 5 and inter[0] == union[0] == 30 * 40 - (30 - 2 * d) * (40 - 2 * d)


@pytest.mark.parametrize("shape", [(0, 0), (0, 5), (4, 0)])
def test_an_empty_image_counts_nothing(shape):
    inter, union = boundary_iou(np.zeros(shape, np.uint8), np.zeros(shape, np.uint8), 3)
    assert inter.tolist() == union.tolist() == [0, 0, 0]


def test_a_band_wider_than_any_int32_box_sum_is_every_pixel():
    """d = 5000 (a 250,000-pixel diagonal's band, past the byte box sum's int32 range) on a
    small image: every pixel is within d of the border, so each class's boundary is its mask."""
    rng = np.random.default_rng(8)
    gt, pred = blobs(rng, (30, 40), 3), blobs(rng, (30, 40), 3)
    gt[:4, :6] = 255
    assert boundary_width(gt.shape, 100.0) == 5000
    inter, union = boundary_iou(pred, gt, 3, dilation_ratio=100.0)
    valid = gt != 255
    for c in range(3):
        assert inter[c] == ((gt == c) & (pred == c) & valid).sum()
        assert union[c] == (((gt == c) | (pred == c)) & valid).sum()


def test_torch_tensors_and_integer_types_give_the_same_sums():
    rng = np.random.default_rng(3)
    gt, pred = blobs(rng, (33, 47), 4), blobs(rng, (33, 47), 4)
    expected = boundary_iou(pred, gt, 4, 0.05)
    got = boundary_iou(
        torch.from_numpy(pred).long(), torch.from_numpy(gt.astype(np.int32)), 4, 0.05
    )
    for a, b in zip(expected, got, strict=True):
        np.testing.assert_array_equal(a, b)


def Z(shape):
    return np.zeros(shape, np.int64)


@pytest.mark.parametrize(
    ("pred", "gt", "kwargs", "match"),
    [
        (Z((4, 5)), Z((5, 4)), {}, "differ in shape"),
        (Z((2, 4, 5)), Z((2, 4, 5)), {}, "one H×W label image"),
        (Z((4, 5)), Z((4, 5)) + 7, {}, r"ground truth holds ids \[7\] outside the"),
        (Z((4, 5)) + 3, Z((4, 5)), {}, r"prediction holds ids \[3\] outside the"),
        (Z((4, 5)) - 1, Z((4, 5)), {}, r"prediction holds ids \[-1\]"),
        (Z((4, 5)), Z((4, 5)), {"dilation_ratio": 0}, "must be a positive finite"),
        (Z((4, 5)), Z((4, 5)), {"dilation_ratio": float("inf")}, "must be a positive finite"),
        (Z((4, 5)), Z((4, 5)), {"num_classes": 300}, r"in \[1, 255\]"),
        (np.zeros((4, 5), np.float32), Z((4, 5)), {}, "integer class ids, got dtype float32"),
    ],
)
def test_bad_inputs_say_what_is_wrong(pred, gt, kwargs, match):
    with pytest.raises(ValueError, match=match):
        boundary_iou(pred, gt, **{"num_classes": 3, **kwargs})

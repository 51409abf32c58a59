"""Boundary IoU of one image, per class, as sums (Cheng, Girshick, Dollár, Berg, Kirillov 2021).

The definition, as the authors' reference code has it: for a binary mask M of an H×W image,
``d = max(1, round(dilation_ratio · sqrt(H² + W²)))``; M is padded with one pixel of zeros and
eroded ``d`` times by a 3×3 square, and ``boundary(M) = M − erosion`` (so the image border counts
as an edge). For class c, ``G = boundary(truth == c)`` and ``P = boundary(prediction == c)``; an
image stores ``|G ∩ P|`` and ``|G ∪ P|`` over the pixels whose ground truth is not the ignore
index. A group's Boundary IoU of c is the sum of its images' intersections over the sum of their
unions, as IoU is from a summed confusion; mBoundaryIoU is the NaN-mean over classes.

Here every class comes from one pass over each label image, not ``d`` erosions per class:

- ``d`` erosions by a 3×3 square keep the pixels of M whose (2d+1)² square neighbourhood lies
  in M and inside the image, so a pixel of class c is in ``boundary(mask == c)`` iff within
  chessboard distance ``d`` of a pixel of another label or of the outside;
- the nearest such pixel is one step past an *edge pixel* of class c (a pixel with a
  differently labelled 8-neighbour, or on the image's border), and no edge pixel of another
  class is nearer; so the condition is: an edge pixel (of any class) within distance ``d − 1``;
- edge pixels are where the 3×3 maximum and minimum of the labels differ; "within
  ``d − 1``" is a (2d−1)² box sum over them being positive (a running sum, whatever ``d``),
  taken in bytes: edges are 255, so any positive sum saturates to 255 and the box is a 0/255
  mask at once;
- intersections and unions of every class come from one joint count of (truth, prediction)
  keys (:mod:`claravid.eval.measures.joint_counts`), a key being the class where the pixel is
  in its image's boundary band.

``tests/eval/measures/test_boundary.py`` holds the plain definition (the erosions) as the oracle.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from claravid.eval.measures.joint_counts import joint_counts
from claravid.eval.measures.label_ids import check_ids, check_num_classes, label_image

#: The reference's dilation ratio: d = 101 pixels on a 4032×3024 frame.
DILATION_RATIO = 0.02

_SQUARE = np.ones((3, 3), np.uint8)


def boundary_width(shape: tuple[int, int], dilation_ratio: float = DILATION_RATIO) -> int:
    """``d = max(1, round(dilation_ratio · sqrt(H² + W²)))`` for an image of ``shape`` = (H, W).

    Python's ``round`` (half to even), as the reference code.
    """
    height, width = shape
    return max(1, round(dilation_ratio * math.sqrt(height**2 + width**2)))


def boundary_iou(
    pred: Any, gt: Any, num_classes: int, dilation_ratio: float = DILATION_RATIO
) -> tuple[np.ndarray, np.ndarray]:
    """Per-class boundary intersections and unions of one image: int64 [K] each.

    Args:
        pred: predicted class ids, H×W (numpy array or torch tensor, any integer type).
        gt: ground-truth class ids, H×W; pixels of the ignore index (255) do not count, but they
            are not class c, so the boundary of c runs along them as along any other label.
        num_classes: K (at most 255).
        dilation_ratio: boundary width as a fraction of the image diagonal (0.02: the paper's).

    Returns:
        ``(intersections, unions)``: ``|G_c ∩ P_c|`` and ``|G_c ∪ P_c|`` for c in 0..K-1. A class
        with union 0 in a group is left out of the group's mean, as for mIoU.

    Raises:
        ValueError: shapes differ or are not 2-D, a non-positive ``dilation_ratio``, or an id
            outside ``[0, K)`` (other than 255 in the ground truth, or anything in the
            prediction under ignored pixels).
    """
    k = check_num_classes(num_classes)
    truth = label_image(gt, "ground truth")
    prediction = label_image(pred, "prediction")
    if truth.shape != prediction.shape:
        raise ValueError(
            f"prediction {prediction.shape} and ground truth {truth.shape} differ in shape"
        )
    if not (0 < dilation_ratio < math.inf):  # inf: a width no image has (an OverflowError)
        raise ValueError(
            f"dilation_ratio must be a positive finite fraction of the diagonal (the paper's "
            f"{DILATION_RATIO}), got {dilation_ratio}"
        )
    valid = check_ids(truth, prediction, k, "")
    if truth.size == 0:
        return np.zeros(k, np.int64), np.zeros(k, np.int64)
    d = boundary_width(truth.shape, dilation_ratio)
    # Keys: the class id inside the image's boundary band, 255 outside it (and where ignored);
    # written over the band masks (no 12-Mpixel image allocated more than needed).
    truth_key = band(truth, d)
    cv2.bitwise_or(truth, cv2.bitwise_not(truth_key, dst=truth_key), dst=truth_key)
    pred_key = cv2.bitwise_and(band(prediction, d), valid, dst=valid)
    cv2.bitwise_or(prediction, cv2.bitwise_not(pred_key, dst=pred_key), dst=pred_key)
    return _intersections_unions(truth_key, pred_key, k)


def band(labels: np.ndarray, d: int) -> np.ndarray:
    """uint8 H×W, 255 where a pixel is in the boundary (width ``d``) of its label's mask, else 0."""
    edges = cv2.dilate(labels, _SQUARE)
    out = cv2.erode(labels, _SQUARE)  # the 3×3 minimum, then (its buffer reused) the band
    cv2.compare(edges, out, cv2.CMP_NE, dst=edges)  # 255 where the 3×3 max and min differ
    edges[0], edges[-1], edges[:, 0], edges[:, -1] = 255, 255, 255, 255  # the padding differs
    side = 2 * d - 1
    if side * side * 255 < 1 << 31:  # OpenCV's running sum is int32
        # Sums of 255s saturate in bytes: 255 where an edge pixel is near, 0 where none is.
        return cv2.boxFilter(edges, cv2.CV_8U, (side, side), dst=out, normalize=False)
    # A diagonal past 72,000 pixels: count 1s, then mark the positive sums.
    cv2.threshold(edges, 0, 1, cv2.THRESH_BINARY, dst=edges)
    cv2.boxFilter(edges, cv2.CV_8U, (side, side), dst=out, normalize=False)
    return cv2.compare(out, 0, cv2.CMP_NE, dst=out)  # type: ignore[call-overload]


def _intersections_unions(
    truth_key: np.ndarray, pred_key: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per class: |G ∩ P| (both keys c) and |G ∪ P| = |G| + |P| − |G ∩ P|, as int64 [K]."""
    joint = joint_counts(truth_key, pred_key)
    both = np.diagonal(joint)[:k].copy()
    return both, joint[:k].sum(axis=1) + joint[:, :k].sum(axis=0) - both

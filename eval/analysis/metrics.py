"""The scores computed from a confusion matrix, and the conventions every report states.

Conventions, stated in every report (`CONVENTION`):

- a confusion matrix counts pixels whose ground truth is not the ignore index, rows = ground
  truth, columns = prediction;
- IoU of a class = TP / (TP + FP + FN) of a summed confusion; a class with union 0 is left out
  of the mean (NaN), never counted as 0 or 1;
- the mIoU of a group of images is computed from the group's summed confusion, never as a mean
  of per-image mIoUs; an image's own mIoU likewise from its own confusion;
- pixel accuracy = correct / valid pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

CONVENTION = (
    "Confusion over pixels whose ground truth is not the ignore index (255); IoU = TP/(TP+FP+FN) "
    "from the group's summed confusion; classes with union 0 are left out of the mean (NaN-mean); "
    "the mIoU of a group (bin, mission, split) comes from its summed confusion, not from a mean of "
    "per-image mIoUs; pixel accuracy = correct / valid pixels."
)


def iou_per_class(confusion: ArrayLike) -> np.ndarray:
    """IoU of each class (float64 [K]); NaN where the class has union 0."""
    conf = np.asarray(confusion, dtype=np.float64)
    tp = np.diag(conf)
    union = conf.sum(axis=0) + conf.sum(axis=1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / np.where(union > 0, union, 1), np.nan)


def mean_iou(confusion: ArrayLike) -> float:
    """NaN-mean of the per-class IoU; NaN when no class has any pixel."""
    iou = iou_per_class(confusion)
    return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")


def pixel_accuracy(confusion: ArrayLike) -> float:
    """Correct / valid pixels; NaN when there is no valid pixel."""
    conf = np.asarray(confusion, dtype=np.float64)
    total = conf.sum()
    return float(np.trace(conf) / total) if total > 0 else float("nan")


def finite_or_none(value: float) -> float | None:
    """A JSON-safe number: NaN and infinities become None (``null``)."""
    return float(value) if np.isfinite(value) else None


def confusion_scores(confusion: ArrayLike, classes: Sequence[str]) -> dict[str, Any]:
    """``{"miou", "pixel_acc", "per_class_iou": {class: iou}}``, NaN written as None."""
    conf = np.asarray(confusion)
    if conf.shape != (len(classes), len(classes)):
        raise ValueError(f"confusion {conf.shape} does not match {len(classes)} classes")
    iou = iou_per_class(conf)
    return {
        "miou": finite_or_none(mean_iou(conf)),
        "pixel_acc": finite_or_none(pixel_accuracy(conf)),
        "per_class_iou": {
            name: finite_or_none(value) for name, value in zip(classes, iou, strict=True)
        },
    }

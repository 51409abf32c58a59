"""The per-image measures beside the confusion: Boundary IoU and calibration sums.

A model's image goes through the sliding windows once (:mod:`claravid.eval.inference.windows`);
its logits give the prediction (argmax) and, for calibration, each pixel's confidence, the
largest softmax probability ``1 / Σ_k exp(l_k − max_l)`` (one reduction on the model's device;
the class probabilities are never copied off it, and a PyTorch model's confidences are binned
there too: only the per-bin integers come back). With test-time augmentation the prediction
and the confidence are the argmax and the largest of the probabilities averaged over the
copies (:mod:`claravid.eval.inference.augment`), so calibration and Boundary IoU score what
the augmented model predicts. The sums themselves are
:func:`claravid.eval.measures.boundary.boundary_iou` and
:func:`claravid.eval.measures.calibration_sums.calibration_sums`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from claravid.data.palette_fold import PaletteFold
from claravid.eval.inference.windows import (
    Model,
    WindowConfig,
    class_probabilities,
    sliding_window_logits,
)
from claravid.eval.measures.boundary import DILATION_RATIO, boundary_iou
from claravid.eval.measures.calibration_sums import N_BINS as CALIBRATION_BINS
from claravid.eval.measures.calibration_sums import calibration_sums


@dataclass(frozen=True)
class ImageMeasures:
    """Which per-image measures to take beside the confusion.

    Attributes:
        boundary: Boundary IoU intersections and unions per class.
        calibration: per confidence bin the pixel count, confidence sum and correct pixels
            (needs scores: a model, not label maps).
        dilation_ratio: the boundary width as a fraction of the image diagonal.
        bins: the number of confidence bins.
    """

    boundary: bool = False
    calibration: bool = False
    dilation_ratio: float = DILATION_RATIO
    bins: int = CALIBRATION_BINS


def predict_with_confidence(
    model: Model,
    image: torch.Tensor,
    config: WindowConfig,
    confidence: bool,
    fold: PaletteFold | None = None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Train ids [H,W] of an image and, with ``confidence``, each pixel's largest softmax
    probability [H,W] (float32), both on the image's device.

    The prediction is the argmax of the logits, the first class on ties, as the confidence's
    class is; so the confidence is that of the predicted class. With test-time augmentation
    (``config.tta``) both come from the probabilities averaged over the copies. With a ``fold``
    (a fine model scored through another palette, :mod:`claravid.data.palette_fold`), the
    prediction and the confidence are those of the summed probabilities (:func:`folded_scores`).
    """
    if config.tta is not None:
        probs = class_probabilities(model, image, config)
        if not confidence:
            return probs.argmax(0), None
        top, prediction = probs.max(0)
        return prediction, top
    logits = sliding_window_logits(model, image, config)
    if fold is not None:
        top, prediction = folded_scores(logits, fold).max(0)
        return prediction, (top if confidence else None)
    if not confidence:
        return logits.argmax(0), None
    top, prediction = logits.max(0)
    logits -= top  # in place: the logits are this call's own
    return prediction, torch.exp(logits).sum(0).reciprocal_()


def folded_scores(logits: torch.Tensor, fold: PaletteFold) -> torch.Tensor:
    """The fine softmax probabilities summed per palette class [K,H,W] (float32), from the
    window-averaged fine logits [19,H,W] (overwritten: they are the caller's own).

    A class no fine class reaches scores -1, so that it is never the argmax, not even where
    every reachable sum underflows to 0.
    """
    if logits.shape[0] != fold.num_source:
        raise ValueError(
            f"the model gives {logits.shape[0]} classes; the fold expects {fold.num_source}"
        )
    # Softmax in place: a 12-Mpixel frame's 19 float32 maps are 0.9 GB; no second copy.
    logits -= logits.max(0, keepdim=True).values
    logits.exp_()
    logits /= logits.sum(0, keepdim=True)
    matrix = torch.from_numpy(fold.matrix()).to(logits.device)
    scores = (matrix @ logits.reshape(fold.num_source, -1)).reshape(-1, *logits.shape[1:])
    unreachable = torch.from_numpy(~fold.reachable).to(logits.device)
    scores[unreachable] = -1.0
    return scores


def image_measures(
    prediction: torch.Tensor | np.ndarray,
    target: torch.Tensor | np.ndarray,
    num_classes: int,
    measures: ImageMeasures,
    confidence: torch.Tensor | np.ndarray | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """An image's boundary sums (int64 [2, K]: intersections, unions) and calibration sums
    (float64 [3, B]: count, confidence sum, correct), each None when not asked for.

    Raises:
        ValueError: calibration asked for without ``confidence``; shapes or ids that do not fit.
    """
    boundary = calibration = None
    if measures.boundary:
        inter, union = boundary_iou(prediction, target, num_classes, measures.dilation_ratio)
        boundary = np.stack([inter, union]).astype(np.int64)
    if measures.calibration:
        if confidence is None:
            raise ValueError("calibration needs each pixel's confidence (a model's scores)")
        count, conf_sum, correct = calibration_sums(confidence, prediction, target,
                                                    measures.bins, num_classes)  # fmt: skip
        calibration = np.stack([count, conf_sum, correct]).astype(np.float64)
    return boundary, calibration

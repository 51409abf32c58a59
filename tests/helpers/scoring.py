"""Scores counted here with numpy, independently of the code under test."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import torch


def _val_predictions(checkpoint, cfg) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(K, truth, prediction) of each val frame of a run, int64 label images, each frame
    predicted with the run's validation windows (``claravid.eval``'s public
    ``predict_labels``)."""
    from claravid import models
    from claravid.eval.inference.windows import WindowConfig, predict_labels
    from claravid.train.data import build_val_dataset

    model = models.load_checkpoint(checkpoint).eval()
    v, a = cfg.val, cfg.data.augment
    window = WindowConfig(v.window, v.stride, v.scale, v.batch_size, "fp32",
                          mean=tuple(a.mean), std=tuple(a.std))  # fmt: skip
    dataset = build_val_dataset(cfg)
    with torch.no_grad():
        for i in range(len(dataset)):
            sample = dataset[i]
            truth = sample["mask"].numpy().astype(np.int64)
            guess = predict_labels(model, sample["image"], window).numpy().astype(np.int64)
            yield model.num_classes, truth, guess


def _mean_over_present(hits: np.ndarray, union: np.ndarray) -> float:
    """The mean of hits / union over the classes with a non-empty union."""
    return float(np.mean(hits[union > 0] / union[union > 0]))


def miou_by_hand(checkpoint, cfg) -> float:
    """The val mIoU of a checkpoint, counted here with numpy from its predictions.

    Over all val frames, per class: pixels labelled and predicted that class over pixels
    labelled or predicted that class (pixels labelled 255 left out), averaged over the classes
    that occur in either (docs/report-format.md, "Conventions").
    """
    hits = predicted = labelled = None
    for k, truth, guess in _val_predictions(checkpoint, cfg):
        if hits is None:
            hits, predicted, labelled = np.zeros(k), np.zeros(k), np.zeros(k)
        valid = truth != 255
        truth, guess = truth[valid], guess[valid]
        hits += np.bincount(truth[truth == guess], minlength=k)
        predicted += np.bincount(guess, minlength=k)
        labelled += np.bincount(truth, minlength=k)
    assert hits is not None, "no val frame"
    return _mean_over_present(hits, predicted + labelled - hits)


def boundary_by_erosion(mask: np.ndarray, d: int) -> np.ndarray:
    """A mask's boundary as Boundary IoU's reference defines it, restated with numpy only: pad
    one pixel of zeros, erode d times by a 3×3 square (nothing beyond the padded image
    erodes), subtract."""
    height, width = mask.shape
    eroded = np.pad(mask.astype(bool), 1)
    for _ in range(d):
        e = np.pad(eroded, 1, constant_values=True)
        shifted = [e[i : i + height + 2, j : j + width + 2] for i in range(3) for j in range(3)]
        eroded = np.logical_and.reduce(shifted)
    return mask.astype(bool) & ~eroded[1:-1, 1:-1]


def boundary_iou_by_hand(pred, gt, num_classes, ratio=0.02) -> tuple[np.ndarray, np.ndarray]:
    """Per class, |G ∩ P| and |G ∪ P| of the boundaries of the truth's and the prediction's
    class masks (`boundary_by_erosion`, d = the ratio of the image diagonal, at least 1),
    pixels labelled 255 left out."""
    height, width = gt.shape
    d = max(1, round(ratio * math.sqrt(height**2 + width**2)))  # as the reference: int(round())
    valid = gt != 255
    inter, union = [], []
    for c in range(num_classes):
        g = boundary_by_erosion(gt == c, d) & valid
        p = boundary_by_erosion(pred == c, d) & valid
        inter.append(int((g & p).sum()))
        union.append(int((g | p).sum()))
    return np.array(inter), np.array(union)


def boundary_miou_by_hand(checkpoint, cfg) -> float:
    """The val mBoundaryIoU of a checkpoint: per class, summed |G ∩ P| over summed |G ∪ P| of
    the frames' boundaries (`boundary_iou_by_hand`), averaged over the classes with any."""
    inter = union = None
    for k, truth, guess in _val_predictions(checkpoint, cfg):
        i, u = boundary_iou_by_hand(guess, truth, k)
        inter, union = (i, u) if inter is None else (inter + i, union + u)
    assert inter is not None and union is not None, "no val frame"
    return _mean_over_present(inter, union)

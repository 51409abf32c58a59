"""Scores counted here with numpy, independently of the code under test."""

from __future__ import annotations

import numpy as np
import torch


def miou_by_hand(checkpoint, cfg) -> float:
    """The val mIoU of a checkpoint, counted here with numpy from its predictions.

    Each val frame is predicted with the run's validation windows (``claravid.eval``'s public
    ``predict_labels``); then, over all frames, per class: pixels labelled and predicted that
    class over pixels labelled or predicted that class (pixels labelled 255 left out),
    averaged over the classes that occur in either (docs/report-format.md, "Conventions").
    """
    from claravid import models
    from claravid.eval import WindowConfig, predict_labels
    from claravid.train.data import build_val_dataset

    model = models.load_checkpoint(checkpoint).eval()
    v, a = cfg.val, cfg.data.augment
    window = WindowConfig(v.window, v.stride, v.scale, v.batch_size, "fp32",
                          mean=tuple(a.mean), std=tuple(a.std))  # fmt: skip
    k = model.num_classes
    hits, predicted, labelled = np.zeros(k), np.zeros(k), np.zeros(k)
    dataset = build_val_dataset(cfg)
    with torch.no_grad():
        for i in range(len(dataset)):
            sample = dataset[i]
            truth = sample["mask"].numpy().astype(np.int64)
            guess = predict_labels(model, sample["image"], window).numpy()
            valid = truth != 255
            truth, guess = truth[valid], guess[valid]
            hits += np.bincount(truth[truth == guess], minlength=k)
            predicted += np.bincount(guess, minlength=k)
            labelled += np.bincount(truth, minlength=k)
    union = predicted + labelled - hits
    return float(np.mean(hits[union > 0] / union[union > 0]))

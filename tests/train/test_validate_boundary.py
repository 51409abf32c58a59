"""Validation logs mBoundaryIoU beside mIoU, overall and per delentropy bin, checked against the
plain definition of Boundary IoU (repeated 3×3 erosions of each class mask) written here."""

import json

import cv2
import numpy as np
import pytest
import torch

from claravid import models
from claravid.train import load_config, train
from tests.tiny import tiny


def boundary_by_erosion(mask: np.ndarray, ratio: float = 0.02) -> np.ndarray:
    """Cheng et al.'s reference: pad by one zero pixel, erode d times by a 3×3 square, subtract."""
    h, w = mask.shape
    d = max(1, round(ratio * np.sqrt(h * h + w * w)))
    padded = cv2.copyMakeBorder(mask.astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    eroded = cv2.erode(padded, np.ones((3, 3), np.uint8), iterations=d)[1:-1, 1:-1]
    return (mask.astype(np.uint8) - eroded).astype(bool)


def boundary_miou_by_hand(checkpoint, cfg) -> float:
    """The val mBoundaryIoU of a checkpoint: per class, summed |G ∩ P| over summed |G ∪ P| of
    the frames' boundaries (pixels labelled 255 left out), NaN-mean over classes."""
    from claravid.eval import WindowConfig, predict_labels
    from claravid.train.data import build_val_dataset

    model = models.load_checkpoint(checkpoint).eval()
    v, a = cfg.val, cfg.data.augment
    window = WindowConfig(v.window, v.stride, v.scale, v.batch_size, "fp32",
                          mean=tuple(a.mean), std=tuple(a.std))  # fmt: skip
    k = model.num_classes
    inter, union = np.zeros(k), np.zeros(k)
    dataset = build_val_dataset(cfg)
    with torch.no_grad():
        for i in range(len(dataset)):
            sample = dataset[i]
            truth = sample["mask"].numpy().astype(np.int64)
            guess = predict_labels(model, sample["image"], window).numpy()
            valid = truth != 255
            for c in range(k):
                g, p = boundary_by_erosion(truth == c), boundary_by_erosion(guess == c)
                inter[c] += (g & p & valid).sum()
                union[c] += ((g | p) & valid).sum()
    return float(np.mean(inter[union > 0] / union[union > 0]))


@pytest.mark.slow
def test_validation_logs_boundary_iou_per_bin(claravid_root, tmp_path):
    out = tmp_path / "run"
    cfg = load_config("demo", tiny(claravid_root, out, "train.steps=1", "val.every=0",
                                   "train.batch_size=2"))  # fmt: skip
    train(cfg)
    row = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()][-1]
    assert row["boundary_miou"] == pytest.approx(boundary_miou_by_hand(out / "last.pt", cfg))
    assert set(row["boundary_miou_bins"]) == set(row["miou_bins"]) == {"low", "medium", "high"}
    assert all(v is None or 0 <= v <= 1 for v in row["boundary_miou_bins"].values())

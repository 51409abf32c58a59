"""Validation logs mBoundaryIoU beside mIoU, overall and per delentropy bin, checked against the
plain definition of Boundary IoU (repeated 3×3 erosions of each class mask: tests/helpers)."""

import json

import pytest

from claravid.train import load_config, train
from tests.helpers.scoring import boundary_miou_by_hand
from tests.tiny import tiny


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

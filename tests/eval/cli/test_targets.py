"""``claravid-eval --dataset uavid|folder``: keys mirror relative paths; hand-made cases."""

import json

import cv2
import numpy as np
import pytest

from claravid.data.palettes import load_palette
from claravid.eval.cli.evaluate import main

COLORS = load_palette("uavid").colors


@pytest.fixture
def uavid(tmp_path):
    """uavid_val with 2 sequences of one 32×24 frame each: left half Building, right half Tree."""
    rng = np.random.default_rng(0)
    ids = np.zeros((24, 32), np.uint8)
    ids[:, :16], ids[:, 16:] = 1, 4
    for seq in (1, 2):
        base = tmp_path / "uavid" / "uavid_val" / f"seq{seq}"
        (base / "Images").mkdir(parents=True)
        (base / "Labels").mkdir(parents=True)
        image = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
        cv2.imwrite(str(base / "Images" / "000000.png"), image)
        cv2.imwrite(str(base / "Labels" / "000000.png"), COLORS[ids][..., ::-1])
    return tmp_path / "uavid", ids


def test_uavid_predictions_by_hand(uavid, tmp_path):
    root, ids = uavid
    preds = tmp_path / "preds"
    for seq, pred in ((1, ids), (2, np.full_like(ids, 1))):  # perfect; all Building
        target = preds / "uavid_val" / f"seq{seq}" / "Images" / "000000.png"
        target.parent.mkdir(parents=True)
        cv2.imwrite(str(target), pred)
    out = tmp_path / "rep"
    argv = ["--predictions", str(preds), "--dataset", "uavid", "--data", str(root),
            "--split", "val", "--bins", "1", "--output", str(out), "--no-progress",
            "--palette", "uavid"]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["palette"] == "uavid"
    perfect, building = report["images"]
    assert perfect["miou"] == 1.0
    # All Building on half Building, half Tree: IoU(Building) = 1/2, IoU(Tree) = 0.
    assert building["miou"] == pytest.approx(0.25) and building["pixel_acc"] == 0.5
    # Summed: Building TP 768, FP 384 -> 768/1152; Tree TP 384, FN 384 -> 1/2.
    assert report["overall"]["miou"] == pytest.approx((768 / 1152 + 0.5) / 2)
    assert report["bins"][0]["miou"] == report["overall"]["miou"]
    assert main([*argv[:-3], "--group-by", "mission", "--output", str(tmp_path / "x")]) == 2


def test_folder_dataset_with_id_masks(tmp_path):
    """FolderSegmentation: images/a/x.jpg with masks/a/x.png (udd6 ids); keys mirror paths."""
    images, masks, preds = tmp_path / "images", tmp_path / "masks", tmp_path / "preds"
    truth = np.zeros((20, 30), np.uint8)
    truth[:, 10:] = 3  # a third Other (0), two thirds Vegetation (3)
    for folder in (images, masks, preds):
        (folder / "a").mkdir(parents=True)
    cv2.imwrite(str(images / "a" / "x.jpg"), np.full((20, 30, 3), 128, np.uint8))
    cv2.imwrite(str(masks / "a" / "x.png"), truth)
    cv2.imwrite(str(preds / "a" / "x.png"), np.full_like(truth, 3))  # all Vegetation
    out = tmp_path / "rep"
    argv = ["--predictions", str(preds), "--dataset", "folder", "--data", str(images),
            "--masks", str(masks), "--palette", "udd6", "--bins", "1", "--output", str(out),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    # Other: TP 0, FN 200 -> 0; Vegetation: TP 400, FP 200 -> 2/3; the 4 absent classes: NaN.
    assert report["overall"]["miou"] == pytest.approx((0 + 2 / 3) / 2)
    assert report["palette"] == "udd6" and len(report["classes"]) == 6
    no_palette = [a for a in argv if a not in ("--palette", "udd6")]
    assert main([*no_palette[:-3], "--output", str(tmp_path / "x")]) == 2

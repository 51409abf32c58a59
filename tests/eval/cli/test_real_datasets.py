"""claravid-eval on the real datasets' own layouts through the syndrone palette: the split is
chosen and recorded, and a tree of the wrong dataset stops in one line before any output."""

import json

import cv2
import numpy as np
import pytest

from claravid.eval.cli.evaluate import main
from tests.helpers.real_trees import HEIGHT, WIDTH, make_tree

# UDD5's ids -> coarse train ids (0 Vegetation -> Nature 1, 1 Building -> Construction 4,
# 2 Road -> Road 0, 3 Vehicle -> Vehicle 3, 4 Other -> ignore), written out by hand.
UDD5_TO_COARSE = np.array([1, 4, 0, 3, 255], np.uint8)


@pytest.fixture
def udd5(tmp_path):
    root = tmp_path / "udd5"
    make_tree(root, "udd5")
    preds = tmp_path / "preds"
    for gt in sorted(root.rglob("gt/*.png")):
        coarse = UDD5_TO_COARSE[cv2.imread(str(gt), cv2.IMREAD_UNCHANGED)]
        pred = np.where(coarse == 255, 5, coarse).astype(np.uint8)  # ignored pixels: anything
        key = gt.relative_to(root).parent.parent / "src" / gt.name
        (preds / key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(preds / key), pred)
    return root, preds


def _argv(root, preds, out, dataset, split):
    return ["--predictions", str(preds), "--dataset", dataset, "--data", str(root), "--split",
            split, "--palette", "syndrone", "--bins", "1", "--output", str(out),
            "--no-progress"]  # fmt: skip


@pytest.mark.parametrize(("split", "images"), [("train", 2), ("all", 4)])
def test_udd5_scored_on_the_split_asked_and_the_report_says_which(udd5, tmp_path, split, images):
    root, preds = udd5
    out = tmp_path / f"rep_{split}"
    assert main(_argv(root, preds, out, "udd5", split)) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["overall"]["miou"] == 1.0
    assert json.dumps(report).count(f'"split": "{split}"') >= 1
    assert report["overall"]["num_images"] == images
    assert (HEIGHT, WIDTH) == (20, 28)


def test_a_udd5_tree_read_as_udd6_stops_in_one_line_writing_nothing(udd5, tmp_path, capsys):
    root, preds = udd5
    out = tmp_path / "rep"
    assert main(_argv(root, preds, out, "udd6", "train")) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("claravid-eval: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "this is a UDD5 tree" in lines[0] and "--dataset udd5" in lines[0]
    assert not out.exists()


def test_uavid_through_syndrone_on_all_labelled_images(tmp_path):
    root = tmp_path / "uavid"
    truth = make_tree(root, "uavid")
    preds = tmp_path / "preds"
    for label in truth:  # every prediction Construction: only UAVid's Building (1/8) is right
        image = label.replace("/Labels/", "/Images/")
        (preds / image).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(preds / image), np.full((HEIGHT, WIDTH), 4, np.uint8))
    out = tmp_path / "rep"
    assert main(_argv(root, preds, out, "uavid", "all")) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["overall"]["num_images"] == 4 and '"split": "all"' in json.dumps(report)
    # Clutter is ignored; Construction's IoU = Building pixels / all non-ignored pixels.
    names = [n for label in truth.values() for n in label]
    scored = sum(n != "Clutter" for n in names)
    iou = report["overall"]["per_class_iou"]
    assert iou["Construction"] == pytest.approx(names.count("Building") / scored)  # 70/490
    # Obstacle and Water: in no label and never predicted (union 0), left out of the mean.
    assert iou["Obstacle"] is None and iou["Water"] is None
    assert report["overall"]["miou"] == pytest.approx((1 / 7) / 5)

"""A 1x1 image, with its mask, through every measure and through claravid-eval on a folder
dataset: counted by hand, never an OpenCV error (OpenCV reads a 1x1 array as a scalar)."""

import json
import re

import cv2
import numpy as np
import pytest

from claravid.eval.cli.evaluate import main as eval_main
from claravid.eval.measures.boundary import boundary_iou
from claravid.eval.measures.calibration_sums import calibration_bins
from claravid.eval.measures.cross_view import cross_view
from claravid.io.layout import scaled_intrinsics

ONE = (1, 1)


def _px(value):
    return np.full(ONE, value, np.uint8)


def test_boundary_iou_of_one_pixel():
    # The one pixel lies on the image border: it is in the boundary of its class in both images.
    inter, union = boundary_iou(_px(2), _px(2), 3)
    assert inter.tolist() == [0, 0, 1] and union.tolist() == [0, 0, 1]
    inter, union = boundary_iou(_px(1), _px(2), 3)  # predicted 1, truth 2: each class one pixel
    assert inter.tolist() == [0, 0, 0] and union.tolist() == [0, 1, 1]
    inter, union = boundary_iou(_px(1), _px(255), 3)  # ignored: nothing counts
    assert inter.tolist() == [0, 0, 0] and union.tolist() == [0, 0, 0]
    with pytest.raises(ValueError, match=r"ground truth holds ids \[7\]"):
        boundary_iou(_px(1), _px(7), 3)
    with pytest.raises(ValueError, match=r"prediction holds ids \[9\]"):
        boundary_iou(_px(9), _px(1), 3)


def test_calibration_bins_of_one_pixel():
    probs = np.array([0.2, 0.7, 0.1], np.float32).reshape(3, 1, 1)
    count, conf_sum, correct = calibration_bins(probs, _px(1))
    # 0.7 falls in bin 10 of 15 ([10/15, 11/15)); predicted 1, truth 1: correct.
    assert count.tolist() == [0] * 10 + [1] + [0] * 4
    assert conf_sum[10] == float(np.float32(0.7)) and conf_sum.sum() == conf_sum[10]
    assert correct.tolist() == count.tolist()
    assert calibration_bins(probs, _px(255))[0].sum() == 0
    assert calibration_bins(probs, _px(0))[2].sum() == 0  # wrong: counted, not correct


def test_cross_view_of_one_pixel():
    depth = np.full(ONE, 10.0, np.float32)
    c2w_t = np.eye(4)
    c2w_s = np.eye(4)
    c2w_s[0, 3] = 1e-3  # 1 mm aside at 10 m: the pixel lands on itself
    sums = cross_view(depth, depth, c2w_t, c2w_s, scaled_intrinsics((1, 1)), _px(3), _px(3),
                      _px(3), _px(2), num_classes=4)  # fmt: skip
    assert (sums.status, sums.pixels, sums.kept, sums.agree, sums.gt_agree) == ("ok", 1, 1, 1, 0)
    assert sums.intersection.tolist() == [0, 0, 0, 1] and sums.union.tolist() == [0, 0, 0, 1]
    assert sums.gt_intersection.tolist() == [0, 0, 0, 0]
    assert sums.gt_union.tolist() == [0, 0, 1, 1]


@pytest.mark.parametrize("source", ["predictions", "checkpoint"])
def test_claravid_eval_of_a_one_pixel_folder_dataset(tmp_path, model_files, source):
    images, masks, preds = tmp_path / "images", tmp_path / "masks", tmp_path / "preds"
    for folder in (images, masks, preds):
        folder.mkdir()
    cv2.imwrite(str(images / "x.png"), np.full((1, 1, 3), 128, np.uint8))
    cv2.imwrite(str(masks / "x.png"), _px(3))
    cv2.imwrite(str(preds / "x.png"), _px(3))
    out = tmp_path / "rep"
    given = (["--predictions", str(preds)] if source == "predictions"
             else ["--checkpoint", str(model_files["plain"]), "--window", "28",
                   "--calibration"])  # fmt: skip
    argv = [*given, "--dataset", "folder", "--data", str(images), "--masks", str(masks),
            "--palette", "uavid", "--bins", "1", "--output", str(out), "--no-progress",
            "--hardest", "0", "--bootstrap", "0"]  # fmt: skip
    assert eval_main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    (image,) = report["images"]
    if source == "predictions":  # the one pixel right: every measure says so
        assert image["miou"] == 1.0
        assert report["overall"]["boundary_iou"]["miou"] == 1.0
    else:  # with the model's scores: calibration counts the one pixel
        assert report["quality"]["calibration"]["status"] == "computed"
    assert report["quality"]["boundary_iou"]["status"] == "computed"


def test_sky_in_both_frames_of_a_pair_is_never_kept():
    # The sky (depth exactly 1000 m) in the same rows of both frames: carried onto itself, it
    # would pass the visibility test; only the "hit" condition (0 < d < 1000 m) drops it. The
    # tests had sky in one frame alone, which visibility drops anyway.
    depth = np.full((6, 8), 10.0, np.float32)
    depth[:2] = 1000.0  # two rows of sky, 16 pixels
    c2w_s = np.eye(4)
    c2w_s[0, 3] = 1e-3  # 1 mm aside: every pixel lands on itself
    labels = np.full((6, 8), 1, np.uint8)
    sums = cross_view(depth, depth, np.eye(4), c2w_s, scaled_intrinsics((8, 6)), labels, labels,
                      labels, labels, num_classes=2)  # fmt: skip
    assert (sums.status, sums.pixels, sums.kept, sums.agree) == ("ok", 48, 32, 32)


@pytest.mark.parametrize(
    ("count", "conf_sum", "correct", "says"),
    [([2, -1], [1.0, 0.0], [1, 0], "negative in bin(s) [1]"),
     ([2, 1], [1.0, 0.5], [3, 0], "more correct pixels than pixels in bin(s) [0]"),
     ([2, 1], [1.0, float("nan")], [1, 0], "not finite in bin(s) [1]"),
     ([2, 1], [2.5, 0.5], [1, 0], "a confidence sum above the pixel count in bin(s) [0]")],
)  # fmt: skip
def test_calibration_errors_refuse_sums_no_image_gives(count, conf_sum, correct, says):
    from claravid.eval.analysis.calibration import calibration_errors

    with pytest.raises(ValueError, match=re.escape(says)):  # before: NaN, silently
        calibration_errors(count, conf_sum, correct)
    assert calibration_errors([2, 1], [1.0, 0.5], [1, 0]) == pytest.approx((0.5 / 3, 0.5))


def test_a_zero_one_dynamic_mask_is_refused_saying_how_to_convert_it():
    depth = np.full((6, 8), 10.0, np.float32)
    c2w_s = np.eye(4)
    c2w_s[0, 3] = 1e-3
    labels = np.ones((6, 8), np.uint8)
    moving = np.zeros((6, 8), np.uint8)
    moving[0, 0] = 1  # 0/1: before, every pixel read as moving and the pair blamed "a turn"
    with pytest.raises(ValueError, match=r"dynamic_t holds 0 and 1, not the 0/255"):
        cross_view(depth, depth, np.eye(4), c2w_s, scaled_intrinsics((8, 6)), labels, labels,
                   labels, labels, moving, None, num_classes=2)  # fmt: skip

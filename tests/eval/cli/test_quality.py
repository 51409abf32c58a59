"""The measures beyond mIoU through the whole ``claravid-eval``, on cases small enough to count
by hand: Boundary IoU of two half-and-half masks, the ECE of a model whose logits are constant,
the cross-view consistency of three nadir frames over flat ground shifted by 8 pixels each."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from claravid.data.palettes import load_palette
from claravid.eval.cli.evaluate import main
from claravid.io import modalities
from claravid.io.layout import FOCAL_PX, IMAGE_SIZE


def constant_onnx(path, bias):
    """An ONNX model whose logits are ``bias`` at every pixel (a 1×1 convolution with zero
    weights): every pixel's confidence is softmax(bias)'s largest value."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    k = len(bias)
    weight = numpy_helper.from_array(np.zeros((k, 3, 1, 1), np.float32), "w")
    offset = numpy_helper.from_array(np.asarray(bias, np.float32), "b")
    node = helper.make_node("Conv", ["image", "w", "b"], ["logits"])
    graph = helper.make_graph(
        [node], "constant",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["n", 3, "h", "w"])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["n", k, "h", "w"])],
        initializer=[weight, offset],
    )  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


@pytest.fixture
def halves(tmp_path):
    """One 8×6 image: ground truth class 0 in columns 0-3, class 1 in 4-7 (udd6 ids)."""
    images, masks = tmp_path / "images", tmp_path / "masks"
    truth = np.zeros((6, 8), np.uint8)
    truth[:, 4:] = 1
    for folder in (images, masks):
        folder.mkdir()
    cv2.imwrite(str(images / "x.png"), np.full((6, 8, 3), 128, np.uint8))
    cv2.imwrite(str(masks / "x.png"), truth)
    common = ["--dataset", "folder", "--data", str(images), "--masks", str(masks), "--palette",
              "udd6", "--bins", "1", "--no-progress", "--bootstrap", "0"]  # fmt: skip
    return tmp_path, truth, common


def test_boundary_iou_by_hand(halves):
    tmp, truth, common = halves
    preds = tmp / "preds"
    preds.mkdir()
    pred = np.zeros_like(truth)
    pred[:, 5:] = 1  # the edge one column to the right
    cv2.imwrite(str(preds / "x.png"), pred)
    assert main(["--predictions", str(preds), *common, "--output", str(tmp / "rep")]) == 0
    report = json.loads((tmp / "rep" / "report.json").read_text())
    # d = max(1, round(0.02 · 10)) = 1: a pixel is boundary when its 3×3 neighbourhood leaves
    # its mask or the image. Class 0: truth's boundary is columns 0 and 3 and rows 0 and 5 of
    # columns 0-3 (16 pixels), the prediction's columns 0 and 4 and rows 0 and 5 of 0-4 (18);
    # they share column 0 and rows 0, 5 of columns 1-3: 12, union 22. Class 1: truth's 16,
    # the prediction's columns 5 and 7 and rows 0, 5 of column 6 (14); shared: column 7 and
    # rows 0, 5 of columns 5-6: 10, union 20.
    boundary = report["overall"]["boundary_iou"]
    assert boundary["per_class_iou"]["Other"] == pytest.approx(12 / 22)
    assert boundary["per_class_iou"][report["classes"][1]] == pytest.approx(10 / 20)
    assert boundary["miou"] == pytest.approx((12 / 22 + 10 / 20) / 2)
    assert report["images"][0]["boundary_iou"] == pytest.approx((12 / 22 + 10 / 20) / 2)
    assert report["quality"]["calibration"]["status"] == "unavailable"
    assert "no scores" in report["quality"]["calibration"]["reason"]
    assert report["quality"]["consistency"]["status"] == "unavailable"
    text = (tmp / "rep" / "report.md").read_text()
    assert "## Boundary IoU per complexity bin" in text and "Calibration: unavailable" in text


def test_ece_and_boundary_of_constant_logits_by_hand(halves):
    tmp, _, common = halves
    model = constant_onnx(tmp / "constant.onnx", [1.0, 0, 0, 0, 0, 0])
    argv = ["--onnx", str(model), *common, "--window", "14x14", "--statistics", "imagenet",
            "--output", str(tmp / "rep")]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((tmp / "rep" / "report.json").read_text())
    # Every pixel: class 0 predicted with confidence e / (e + 5); half the pixels are class 0.
    confidence = np.e / (np.e + 5)
    cal = report["overall"]["calibration"]
    assert cal["ece"] == pytest.approx(abs(0.5 - confidence), rel=1e-6)
    assert cal["mce"] == pytest.approx(abs(0.5 - confidence), rel=1e-6)
    assert cal["num_pixels"] == 48
    assert cal["reliability"]["count"][int(confidence * 15)] == 48
    assert cal["reliability"]["accuracy"][int(confidence * 15)] == pytest.approx(0.5)
    # The prediction is class 0 everywhere: its boundary is the 1-pixel ring (24 pixels); the
    # truth's class 0 boundary (16) shares 12 with it; class 1 has no predicted boundary: 0.
    assert report["overall"]["boundary_iou"]["miou"] == pytest.approx((12 / 28 + 0) / 2)
    assert (tmp / "rep" / "reliability.png").is_file()


# --------------------------------------------------------------------------------------------
# Three nadir frames 50 m over flat ground, each 8 pixels (8 · 50 / fx metres) east of the last.

WIDTH, HEIGHT, SHIFT, ALTITUDE = 64, 48, 8, 50.0
FX = FOCAL_PX * WIDTH / IMAGE_SIZE[0]
VIEW = "003_urban_1/{m}/45deg_low_h/{stem}.{ext}"


def nadir_tree(root):
    """A ClaraVid tree of 3 frames of one pass: ground of class Building (0) west of x = 0 and
    Road (6) east of it, so frame i sees the edge at column 32 − 8·i."""
    stems = []
    for i in range(3):
        stem = f"{i:06d}"
        edge = WIDTH // 2 - SHIFT * i
        semantic = np.full((HEIGHT, WIDTH), 6, np.uint8)
        semantic[:, :edge] = 0
        pose = np.eye(4)  # OpenGL axes: x east, y north, the camera looks down (−z)
        pose[:3, 3] = [SHIFT * i * ALTITUDE / FX, 0.0, ALTITUDE]
        files = {m: root / VIEW.format(m=m, stem=stem, ext=e) for m, e in
                 (("left_rgb", "jpg"), ("panoptic_seg", "png"), ("dynamic_mask", "png"),
                  ("depth", "png"), ("extrinsics", "json"))}  # fmt: skip
        rgb = np.where(semantic[..., None] == 0, 90, 160).astype(np.uint8).repeat(3, -1)
        modalities.write_rgb(files["left_rgb"], rgb + np.arange(WIDTH, dtype=np.uint8)[:, None])
        modalities.write_pan_seg(files["panoptic_seg"], semantic, np.zeros_like(semantic))
        modalities.write_dynamic_mask(files["dynamic_mask"], np.full_like(semantic, 255))
        modalities.write_depth(files["depth"], np.full((HEIGHT, WIDTH), ALTITUDE))
        modalities.write_extrinsics(files["extrinsics"], pose)
        stems.append(stem)
    return root


def test_consistency_by_hand(tmp_path):
    root = nadir_tree(tmp_path / "root")
    palette = load_palette("claravid")
    building, road = 0, 6  # train ids of the claravid palette
    assert palette.names[building] == "Building" and palette.names[road] == "Road"
    preds = tmp_path / "preds" / "003_urban_1" / "45deg_low_h"
    preds.mkdir(parents=True)
    for i in range(3):
        pred = np.full((HEIGHT, WIDTH), road, np.uint8)
        pred[:, : WIDTH // 2 - SHIFT * i] = building
        if i == 1:
            pred[:, 40:48] = building  # 8 wrong columns in the middle frame
        cv2.imwrite(str(preds / f"{i:06d}.png"), pred)
    argv = ["--predictions", str(tmp_path / "preds"), "--data", str(root), "--split", "all",
            "--palette", "claravid", "--bins", "1", "--bootstrap", "0", "--no-progress",
            "--output", str(tmp_path / "rep")]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    con = report["overall"]["consistency"]
    # Pixel (u, v) of frame i lands on (u − 8, v) of frame i + 1: 56 of 64 columns are kept.
    assert con["pairs"] == {"ok": 2, "turn": 0, "last": 1, "unavailable": 0,
                            "identical_poses": 0}  # fmt: skip
    assert con["kept_pixels"] == 2 * 56 * HEIGHT
    # Pair (0, 1): frame 0's columns 48-55 land on frame 1's wrong columns 40-47; pair (1, 2):
    # frame 1's wrong columns 40-47 land on frame 2's Road. 8 of 56 columns disagree in each.
    assert con["agreement"] == pytest.approx(48 / 56)
    assert con["agreement_gt"] == pytest.approx(1.0)
    # TC: pair (0, 1) Building 24/32, Road 24/32 columns; pair (1, 2) Building 16/24, Road
    # 32/40; summed per class: Building 40/56, Road 56/72.
    assert con["tc"] == pytest.approx((40 / 56 + 56 / 72) / 2)
    assert con["per_class_tc"]["Building"] == pytest.approx(40 / 56)
    assert con["tc_gt"] == pytest.approx(1.0)
    images = {r["path"].rsplit("/", 1)[-1]: r for r in report["images"]}
    assert images["000000.jpg"]["consistency"] == pytest.approx(48 / 56)
    assert images["000002.jpg"]["consistency"] is None  # the last frame of its pass
    assert (tmp_path / "rep" / "consistency_per_bin.png").is_file()

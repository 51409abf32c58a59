"""``claravid-eval`` with a model: checkpoint and ONNX agree, saved predictions round-trip,
merging and re-binning saved confusions equal a direct run, torchrun equals one process."""

import json
import subprocess

import cv2
import numpy as np
import pytest
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import eval_transforms
from claravid.eval.cli.evaluate import main
from claravid.eval.inference.sources import checkpoint_defaults
from claravid.eval.inference.windows import WindowConfig, predict_labels
from tests.helpers.torchrun import torchrun
from tests.tiny import WINDOW

FIRST = ["001_rural_1/45deg_low_h/000000", "001_rural_1/45deg_low_v/000001",
         "001_rural_1/90deg_high_v/000002"]  # fmt: skip
SECOND = ["003_urban_1/45deg_low_h/000001", "003_urban_1/55deg_mid_h/000000",
          "003_urban_1/90deg_high_v/000002"]  # fmt: skip


@pytest.fixture(scope="module")
def splits(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("splits")
    files = {}
    for name, frames in {"first": FIRST, "second": SECOND, "both": FIRST + SECOND}.items():
        files[name] = tmp / f"{name}.txt"
        files[name].write_text("\n".join(frames) + "\n")
    return files


def _run(out, *argv):
    code = main([*argv, "--output", str(out), "--window", WINDOW, "--no-progress"])
    assert code == 0
    return json.loads((out / "report.json").read_text())


def _without_source(report):
    return {k: v for k, v in report.items() if k != "source"}


def _calibration(report):
    """A report's calibration entries, each path with its numbers (rows, bins, images)."""
    found = {}

    def walk(node, path):
        if isinstance(node, dict):
            for key, value in node.items():
                walk(value, f"{path}/{key}")
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{path}[{i}]")
        elif "calibration" in path or "/ece" in path or "/mce" in path:
            found[path] = node

    walk(_without_source(report), "")
    return found


def _without_calibration(report, also=()):
    """The report less what only a source with scores has (calibration, by definition), and
    the entries named in ``also``."""
    drop = {"calibration", "ece", "mce", "source", *also}

    def strip(node):
        if isinstance(node, dict):
            return {k: strip(v) for k, v in node.items() if k not in drop}
        if isinstance(node, list):
            return [strip(v) for v in node]
        return node

    return strip(report)


def test_checkpoint_rebuilds_data_and_palette_and_matches_a_direct_count(
    model_files, claravid_root, splits, tmp_path, saved_figures
):
    # No --data, no --palette: both come from the checkpoint's training config.
    report = _run(tmp_path / "rep", "--checkpoint", str(model_files["checkpoint"]),
                  "--split", str(splits["both"]), "--group-by", "mission")  # fmt: skip
    assert report["palette"] == "uavid" and len(report["classes"]) == 8
    assert report["source"]["data"] == str(claravid_root)
    assert [g["name"] for g in report["groups"]] == ["rural_1", "urban_1"]
    assert all(g["profile"]["mu"] is not None for g in report["groups"])
    # The counts equal the model's own windows on each frame, counted independently.
    ds = ClaraVidSegmentation(
        claravid_root, split=splits["both"], palette="uavid", transforms=eval_transforms()
    )
    from claravid.models import load_checkpoint

    model = load_checkpoint(model_files["checkpoint"]).eval()
    with np.load(tmp_path / "rep" / "confusions.npz") as saved:
        confusions, delent = saved["confusions"], saved["complexity_delent"]
        paths = [str(p) for p in saved["paths"]]
    preds, masks = [], []
    for i in range(len(ds)):
        sample = ds[i]
        preds.append(predict_labels(model, sample["image"], WindowConfig(size=(42, 56))).numpy())
        masks.append(sample["mask"].numpy())
        expected = np.zeros((8, 8), dtype=np.int64)
        valid = masks[i] != 255
        np.add.at(expected, (masks[i][valid], preds[i][valid]), 1)
        np.testing.assert_array_equal(confusions[i], expected)
    _check_plots(saved_figures, report, confusions, delent, paths, ds, preds, masks)
    # 3 bins: 6.8 x 4 in at 100 dpi (the tiny model's bars are near 0: their size is known)
    assert cv2.imread(str(tmp_path / "rep" / "miou_per_bin.png")).shape == (400, 680, 3)
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "## mIoU per complexity bin" in md and "## Per mission" in md


def _iou(conf):
    """Per-class IoU = TP / (TP + FP + FN), NaN for a class absent from truth and prediction."""
    tp = np.diag(conf).astype(float)
    union = conf.sum(0) + conf.sum(1) - tp
    return np.where(union > 0, tp / np.where(union > 0, union, 1), np.nan)


def _check_plots(figures, report, confusions, delent, paths, ds, preds, masks):
    """What the report's plots show, restated from the confusions counted above: bars of each
    quantile bin's mIoU (images sorted by delentropy then path, split in 3 like
    numpy.array_split, confusions summed), each image at (delentropy, mIoU), the per-class IoU
    of each bin, and the 4 lowest-mIoU images in palette colours (ignored pixels white)."""
    from claravid.data.palettes import load_palette

    order = sorted(range(len(paths)), key=lambda i: (delent[i], paths[i]))
    bins = [confusions[list(part)].sum(0) for part in np.array_split(order, 3)]
    (ax,) = figures["miou_per_bin.png"].axes
    heights = [bar.get_height() for bar in ax.patches]
    np.testing.assert_allclose(heights, [np.nanmean(_iou(c)) for c in bins])
    points = np.asarray(figures["miou_vs_delent.png"].axes[0].collections[0].get_offsets())
    expected = [(delent[i], np.nanmean(_iou(confusions[i]))) for i in range(len(paths))]
    np.testing.assert_allclose(sorted(map(tuple, points)), sorted(expected))
    heat = figures["class_iou_per_bin.png"].axes[0].images[0].get_array()
    grid = np.array([_iou(c) for c in bins]).T  # classes x bins
    np.testing.assert_array_equal(np.ma.getmaskarray(heat), np.isnan(grid))
    np.testing.assert_allclose(heat.filled(np.nan), grid)
    colours = np.full((256, 3), 255, dtype=np.uint8)
    colours[:8] = load_palette("uavid").colors
    mious = [np.nanmean(_iou(c)) for c in confusions]
    hardest = sorted(range(len(paths)), key=lambda i: (mious[i], i))[:4]
    axes = figures["hardest.png"].axes
    assert [axes[3 * r].get_title().splitlines()[0] for r in range(4)] == [
        ds.frames[i].key for i in hardest
    ]
    for r, i in enumerate(hardest):
        rgb = cv2.cvtColor(cv2.imread(paths[i]), cv2.COLOR_BGR2RGB)
        for ax, panel in zip(axes[3 * r : 3 * r + 3],
                             (rgb, colours[masks[i]], colours[preds[i]]), strict=True):  # fmt: skip
            np.testing.assert_array_equal(ax.images[0].get_array(), panel)


def test_windows_come_from_the_checkpoint_unless_given(model_files, splits, tmp_path):
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--split", str(splits["first"]),
            "--no-progress", "--bins", "1"]  # fmt: skip
    assert main([*argv, "--output", str(tmp_path / "a")]) == 0
    source = json.loads((tmp_path / "a" / "report.json").read_text())["source"]
    assert source["window"] == {"size": [28, 28], "stride": [18, 18], "scale": 1.0}
    assert main([*argv, "--output", str(tmp_path / "b"), "--window", "42", "--scale", "0.5"]) == 0
    source = json.loads((tmp_path / "b" / "report.json").read_text())["source"]
    assert source["window"] == {"size": [42, 42], "stride": [28, 28], "scale": 0.5}


def test_checkpoint_defaults_read_a_training_config():
    config = {
        "data": {"root": "/c", "palette": "uavid", "val_dataset": "uavid", "val_root": "/u",
                 "val_split": "val", "split": {"seed": 3, "block_size": 200.0, "junk": 1},
                 "missions": ["urban_1"]},
        "val": {"window": 630, "scale": 0.5, "stride": None, "batch_size": "x"},
    }  # fmt: skip
    assert checkpoint_defaults({"config": config}) == {
        "dataset": "uavid", "data": "/u", "palette": "uavid", "split": "val",
        "split_config": {"seed": 3, "block_size": 200.0}, "missions": ["urban_1"],
        "window": 630, "scale": 0.5,
    }  # fmt: skip
    assert checkpoint_defaults({"config": "not a dict"}) == {}
    assert checkpoint_defaults({}) == {}


def test_plain_checkpoint_needs_data(model_files, tmp_path, capsys):
    code = main(["--checkpoint", str(model_files["plain"]), "--output", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "--data is required" in err and len(err.strip().splitlines()) == 1


def test_wrong_palette_for_the_model(model_files, claravid_root, tmp_path, capsys):
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--palette", "claravid",
            "--split", "all", "--output", str(tmp_path / "o")]  # fmt: skip
    assert main(argv) == 2
    assert "predicts 8 classes but palette claravid has 19" in capsys.readouterr().err


@pytest.mark.slow
def test_onnx_and_pytorch_give_the_same_report(
    model_files, model_onnx, claravid_root, splits, tmp_path
):
    common = ["--data", str(claravid_root), "--palette", "uavid", "--split", str(splits["both"])]
    torch_report = _run(tmp_path / "pt", "--checkpoint", str(model_files["checkpoint"]), *common)
    onnx_report = _run(tmp_path / "onnx", "--onnx", str(model_onnx["onnx"]), *common)
    assert onnx_report["source"]["kind"] == "onnx"
    # Labels, confusions and every count agree exactly; confidences are ONNX Runtime's floats.
    assert _without_calibration(onnx_report) == _without_calibration(torch_report)
    ours, theirs = _calibration(torch_report), _calibration(onnx_report)
    assert ours.keys() == theirs.keys() and ours
    for path, value in ours.items():
        if isinstance(value, float):
            assert theirs[path] == pytest.approx(value, abs=1e-6), path
        else:
            assert theirs[path] == value, path


def test_saved_predictions_give_the_same_report(model_files, claravid_root, splits, tmp_path):
    common = ["--data", str(claravid_root), "--palette", "uavid", "--split", str(splits["both"])]
    preds = tmp_path / "preds"
    direct = _run(tmp_path / "a", "--checkpoint", str(model_files["checkpoint"]), *common,
                  "--save-predictions", str(preds))  # fmt: skip
    key = SECOND[0]
    assert (preds / f"{key}.png").is_file() and (preds / "predictions.json").is_file()
    again = _run(tmp_path / "b", "--predictions", str(preds), *common)
    # Label maps have no scores: everything but calibration is the same, and it is said why.
    # Consistency too, but for pairs whose next frame is outside the split: the checkpoint
    # predicts that frame, the folder has no label map of it (each such pair says so).
    consistency = ("consistency", "consistency_gt", "consistency_ci", "consistency_gt_ci")
    assert _without_calibration(again, consistency) == _without_calibration(direct, consistency)
    pairs = again["quality"]["consistency"]["unavailable"]
    assert pairs and all("no label map of the next frame" in reason for reason in pairs)
    assert direct["quality"]["calibration"]["status"] == "computed"
    assert again["quality"]["calibration"]["status"] == "unavailable"
    assert "no scores" in again["quality"]["calibration"]["reason"]
    # Reusing the folder is allowed (it is ours); a foreign one is not.
    assert main(["--checkpoint", str(model_files["checkpoint"]), *common, "--window", WINDOW,
                 "--save-predictions", str(preds), "--output", str(tmp_path / "c"),
                 "--no-progress"]) == 0  # fmt: skip


def test_merge_of_parts_and_rebinning_equal_one_run(model_files, splits, tmp_path, capsys):
    ckpt = ["--checkpoint", str(model_files["checkpoint"])]
    _run(tmp_path / "p1", *ckpt, "--split", str(splits["first"]))
    _run(tmp_path / "p2", *ckpt, "--split", str(splits["second"]))
    whole = _run(tmp_path / "all", *ckpt, "--split", str(splits["both"]), "--bins", "2",
                 "--group-by", "viewpoint")  # fmt: skip
    merged = tmp_path / "merged"
    argv = ["merge", str(tmp_path / "p2"), str(tmp_path / "p1" / "report.json"),
            "--bins", "2", "--group-by", "viewpoint", "--output", str(merged)]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((merged / "report.json").read_text())
    assert _without_source(report) == _without_source(whole)
    assert report["source"]["kind"] == "merge"

    # Re-bin the merged report with fixed edges = a direct run with those edges.
    values = sorted(r["delent"] for r in whole["images"])
    edges = f"{values[0]!r},{values[2]!r},{values[-1]!r}"
    direct = _run(tmp_path / "edges", *ckpt, "--split", str(splits["both"]), "--edges", edges)
    rebinned = tmp_path / "rebinned"
    assert main(["merge", str(merged), "--edges", edges, "--output", str(rebinned)]) == 0
    again = json.loads((rebinned / "report.json").read_text())
    assert _without_source(again) == _without_source(direct)
    assert [b["num_images"] for b in again["bins"]] == [2, 4]

    # The same image twice, or a foreign file, is refused in one line.
    assert main(["merge", str(tmp_path / "p1"), str(tmp_path / "all"),
                 "--output", str(tmp_path / "x")]) == 2  # fmt: skip
    assert "is in both" in capsys.readouterr().err


@pytest.mark.slow
def test_torchrun_two_processes_equal_one(model_files, splits, tmp_path):
    argv = ["-m", "claravid.eval", "--checkpoint", str(model_files["checkpoint"]), "--split",
            str(splits["both"]), "--window", WINDOW, "--no-progress", "--device", "cpu",
            "--save-predictions", str(tmp_path / "preds2")]  # fmt: skip
    run = subprocess.run(
        [*torchrun(2), *argv, "--output", str(tmp_path / "two")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    assert main([*argv[2:-2], "--output", str(tmp_path / "one")]) == 0
    two = json.loads((tmp_path / "two" / "report.json").read_text())
    one = json.loads((tmp_path / "one" / "report.json").read_text())
    assert _without_source(two) == _without_source(one)
    assert len(list((tmp_path / "preds2").rglob("*.png"))) == 6  # both ranks saved theirs
    with (
        np.load(tmp_path / "two" / "confusions.npz") as a,
        np.load(tmp_path / "one" / "confusions.npz") as b,
    ):
        np.testing.assert_array_equal(a["confusions"], b["confusions"])
        assert a["paths"].tolist() == b["paths"].tolist()
    assert torch.distributed.is_available()


@pytest.mark.slow
def test_unreadable_image_is_named_with_loader_workers(
    model_files, writable_root, tmp_path, capsys
):
    rgb = writable_root / "003_urban_1" / "left_rgb" / "45deg_low_h" / "000001.jpg"
    rgb.write_bytes(rgb.read_bytes()[:300])  # truncated JPEG, read in a DataLoader worker
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--data", str(writable_root),
            "--split", "all", "--window", WINDOW, "--workers", "2", "--no-progress",
            "--output", str(tmp_path / "rep")]  # fmt: skip
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    err = [line for line in lines if "warning: window size" not in line]  # WINDOW is not square
    assert len(err) == 1 and str(rgb) in err[0] and "truncated" in err[0]

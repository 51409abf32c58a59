"""``claravid-eval compare`` and ``claravid-predict``."""

import json

import cv2
import numpy as np
import pytest

from claravid.data.transforms import eval_transforms
from claravid.eval.cli.evaluate import main
from claravid.eval.cli.predict import main as predict_main
from claravid.eval.inference.windows import WindowConfig, predict_labels
from claravid.io import modalities
from tests.tiny import tiny_model


def _report(folder, palette, bins):
    """A minimal report folder written by hand: what --compare reads."""
    folder.mkdir(parents=True)
    rows = [{"name": n, "lo": lo, "hi": hi, "num_images": 2, "miou": m, "pixel_acc": m,
             "per_class_iou": {}} for n, lo, hi, m in bins]  # fmt: skip
    edges = [bins[0][1]] + [b[2] for b in bins]
    report = {
        "overall": {"num_images": 2 * len(bins), "miou": 0.5, "pixel_acc": 0.6,
                    "per_class_iou": {}},
        "bins": rows, "groups": [], "images": [], "correlation": {}, "classes": ["a", "b"],
        "palette": palette, "ignore_index": 255, "convention": "...",
        "source": {"kind": "predictions", "binning": {"method": "fixed", "edges": edges}},
    }  # fmt: skip
    (folder / "report.json").write_text(json.dumps(report))
    return folder / "report.json"


def test_compare_side_by_side_with_gap(tmp_path, capsys):
    a = _report(tmp_path / "synthetic", "uavid", [("[4, 5)", 4, 5, 0.6), ("[5, 6]", 5, 6, 0.4)])
    b = _report(tmp_path / "real", "uavid", [("[4, 5)", 4, 5, 0.7), ("[5, 6]", 5, 6, 0.65)])
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--output", str(out)]) == 0
    captured = capsys.readouterr()
    assert "warning" not in captured.err
    table = captured.out
    assert "synthetic mIoU" in table and "real mIoU" in table
    # gap real − synthetic in mIoU points: 10.0 in the low bin, 25.0 in the high bin
    assert "| [4, 5) | 10.0 |" in table and "| [5, 6] | 25.0 |" in table
    # One panel (no confusions, no gaps): 6 x 4.5 in at 100 dpi, bars of both reports.
    image = cv2.cvtColor(cv2.imread(str(out / "compare.png")), cv2.COLOR_BGR2RGB)
    assert image.shape == (450, 600, 3)
    for rgb in ((31, 119, 180), (255, 127, 14)):  # matplotlib's C0 and C1
        assert (np.abs(image.astype(int) - rgb).sum(axis=2) < 10).sum() > 500
    assert (out / "compare.md").read_text().startswith("# Comparison")


def test_compare_warns_when_edges_or_palettes_differ(tmp_path, capsys):
    a = _report(tmp_path / "a", "uavid", [("[4, 5)", 4, 5, 0.6), ("[5, 6]", 5, 6, 0.4)])
    b = _report(tmp_path / "b", "claravid", [("[4, 4.5)", 4, 4.5, 0.7), ("[4.5, 6]", 4.5, 6, 0.6)])
    assert main(["compare", str(a), str(b)]) == 0
    err = capsys.readouterr().err
    assert "claravid-eval: warning: palettes differ" in err
    assert "claravid-eval: warning: bin edges differ" in err


def test_compare_refuses_foreign_json_in_one_line(tmp_path, capsys):
    a = _report(tmp_path / "a", "uavid", [("[4, 5)", 4, 5, 0.6)])
    foreign = tmp_path / "other.json"
    foreign.write_text(json.dumps({"metric": "delent", "results": []}))
    assert main(["compare", str(a), str(foreign)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other.json is not a claravid-eval report.json" in err[0]
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    assert main(["compare", str(a), str(broken)]) == 2
    assert "cannot read" in capsys.readouterr().err


@pytest.mark.slow
def test_predict_writes_label_maps_and_overlays(claravid_root, tmp_path, capsys):
    from claravid import models

    model = tiny_model(seed=3)
    ckpt = models.save_checkpoint(model, tmp_path / "m.pt")  # plain: no config, 8 classes
    flight = sorted((claravid_root / "003_urban_1" / "left_rgb" / "45deg_low_h").glob("*.jpg"))
    out = tmp_path / "pred"
    argv = ["--checkpoint", str(ckpt), str(flight[0].parent), "--output", str(out),
            "--window", "42", "--palette", "uavid"]  # fmt: skip
    assert predict_main(argv) == 0
    assert "3 label maps" in capsys.readouterr().out
    for path in flight:
        ids = cv2.imread(str(out / f"{path.stem}.png"), cv2.IMREAD_UNCHANGED)
        image = eval_transforms()({"image": modalities.read_rgb(path).transpose(2, 0, 1)})
        expected = predict_labels(model, image["image"], WindowConfig(size=(42, 42))).numpy()
        assert ids.dtype == np.uint8 and ids.shape == (48, 64)
        np.testing.assert_array_equal(ids, expected)
        blend = cv2.imread(str(out / "overlays" / f"{path.stem}.jpg"))
        assert blend.shape == (48, 64, 3)
    # Listed files; two model sources; a foreign output folder.
    one = tmp_path / "one"
    argv = ["--checkpoint", str(ckpt), str(flight[1]), "--output", str(one), "--window", "42"]
    assert predict_main([*argv, "--no-overlays"]) == 0
    assert {p.name for p in one.iterdir()} == {"000001.png", "predictions.json"}
    # A plain checkpoint does not record its palette: overlays need --palette, never a guess.
    assert predict_main([*argv, "--overwrite"]) == 2
    assert "pass --palette for the overlays" in capsys.readouterr().err
    assert predict_main(["--checkpoint", str(ckpt), "--onnx", "m.onnx", str(flight[0]),
                         "--output", str(tmp_path / "x")]) == 2  # fmt: skip
    assert "exactly one of --checkpoint and --onnx" in capsys.readouterr().err
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "a.txt").write_text("x")
    assert predict_main(["--checkpoint", str(ckpt), str(flight[0]), "--output",
                         str(tmp_path / "theirs")]) == 2  # fmt: skip


def test_predict_refuses_a_missing_image(tmp_path, capsys):
    ckpt = tmp_path / "none.pt"
    code = predict_main(["--checkpoint", str(ckpt), str(tmp_path / "nope.jpg"), "--output",
                         str(tmp_path / "o")])  # fmt: skip
    assert code == 2
    assert "nope.jpg not found" in capsys.readouterr().err


def test_compare_markdown_shows_gaps_smaller_than_a_tenth_of_a_point():
    # The demo's int8 export: a gap of 2.8e-5 mIoU whose interval excludes 0 was written
    # "+0.0 [+0.0, +0.0]" next to "**yes**". Decimals now follow the smallest non-zero value.
    from claravid.eval.report.markdown import compare_markdown

    def row(name, gap, ci, p):
        return {"name": name, "paired": True, "gap": gap, "gap_ci": ci, "p_value": p}

    bins = [{"name": n, "lo": 4.0, "hi": 5.0, "num_images": 2, "miou": 0.5} for n in "abc"]
    report = {"palette": "uavid", "overall": {"num_images": 6, "miou": 0.5}, "bins": bins}
    analysis = {
        "baseline": "fp32",
        "comparisons": [{"report": "int8", "paired": True,
            "overall": row("overall", 0.0, [0.0, 0.0], 1.0),
            "bins": [row("a", 2.76e-5, [3.87e-6, 3.36e-5], 0.01),  # points 0.00276 [0.000387, ..]
                     row("b", -0.0009, [-0.0012, -0.0004], 0.002),  # points -0.09 [-0.12, -0.04]
                     row("c", 0.0123, [-0.004, 0.0251], 0.3)]}],  # points 1.23 [-0.4, 2.51]
        "uncertainty": {"level": 0.95, "method": "cluster percentile bootstrap",
                        "resamples": 1000, "num_clusters": 6, "cluster": "block", "seed": 0},
    }  # fmt: skip
    text = compare_markdown([report, report], ["fp32", "int8"], [], analysis)
    assert "| a | +0.0028 [+0.0004, +0.0034] | 0.010 | **yes** |" in text
    assert "| b | -0.09 [-0.12, -0.04] | 0.002 | **yes** |" in text
    assert "| c | +1.2 [-0.4, +2.5] | 0.300 | no |" in text
    assert "| **overall** | +0.0 [+0.0, +0.0] | 1.000 | no |" in text
    # Without intervals (reports without confusions): the same rule for the plain gap.
    small = {**report, "bins": [{**bins[0], "miou": 0.50003}]}
    text = compare_markdown([{**report, "bins": bins[:1]}, small], ["fp32", "int8"], [])
    assert "| a | 0.003 |" in text


def test_predict_window_and_stride_are_width_x_height(model_files, claravid_root, tmp_path, capsys):
    """``--window 56x42``: 56 wide, 42 high, like every size flag."""
    from claravid.models import load_checkpoint

    path = sorted((claravid_root / "003_urban_1" / "left_rgb" / "45deg_low_h").glob("*.jpg"))[0]
    out = tmp_path / "pred"
    argv = ["--checkpoint", str(model_files["checkpoint"]), str(path), "-o", str(out),
            "--window", "56x42", "--stride", "28x14", "--no-overlays", "--no-progress"]  # fmt: skip
    assert predict_main(argv) == 0
    assert capsys.readouterr().err == ""
    settings = json.loads((out / "predictions.json").read_text())["source"]["settings"]
    assert settings["window"] == [42, 56] and settings["stride"] == [14, 28]  # height, width
    model = load_checkpoint(model_files["checkpoint"]).eval()
    image = eval_transforms()({"image": modalities.read_rgb(path).transpose(2, 0, 1)})["image"]
    config = WindowConfig(size=(42, 56), stride=(14, 28))
    expected = predict_labels(model, image, config).numpy()
    np.testing.assert_array_equal(cv2.imread(str(out / f"{path.stem}.png"), -1), expected)

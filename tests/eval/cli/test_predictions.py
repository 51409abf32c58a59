"""``claravid-eval --predictions``: hand-built label maps through the whole command line."""

import json
import shutil

import cv2
import numpy as np
import pytest

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.dsp import image_complexity
from claravid.eval.cli.evaluate import main

FRAMES = ["001_rural_1/45deg_low_h/000000", "003_urban_1/55deg_mid_v/000001",
          "003_urban_1/90deg_high_h/000002"]  # fmt: skip
K = 8  # uavid palette


def _by_hand(truth, pred):
    """Confusion counted pixel by pixel (rows truth, columns prediction), 255 skipped."""
    conf = np.zeros((K, K), dtype=np.int64)
    for t, p in zip(truth.ravel(), pred.ravel(), strict=True):
        if t != 255:
            conf[t, p] += 1
    return conf


def _miou(conf):
    tp = np.diag(conf).astype(float)
    union = conf.sum(0) + conf.sum(1) - tp
    return float(np.mean(tp[union > 0] / union[union > 0]))


@pytest.fixture(scope="module")
def case(claravid_root, tmp_path_factory):
    """Three frames: a perfect prediction, all class 0, every class shifted by one."""
    tmp = tmp_path_factory.mktemp("preds")
    split = tmp / "three.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    ds = ClaraVidSegmentation(claravid_root, split=split, palette="uavid")
    assert [f.key for f in ds.frames] == FRAMES
    preds = tmp / "preds"
    truths, predictions = [], []
    for i, key in enumerate(FRAMES):
        truth = ds.read_mask(i)
        valid = np.where(truth == 255, 0, truth).astype(np.uint8)
        pred = [valid, np.zeros_like(valid), ((valid + 1) % K).astype(np.uint8)][i]
        (preds / key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(preds / f"{key}.png"), pred)
        truths.append(truth)
        predictions.append(pred)
    delent = [image_complexity(f.paths["rgb"]) for f in ds.frames]
    paths = [str(f.paths["rgb"]) for f in ds.frames]
    return {"split": split, "preds": preds, "truths": truths, "predictions": predictions,
            "delent": delent, "paths": paths, "root": claravid_root}  # fmt: skip


def _args(case, out, *extra, preds=None):
    return ["--predictions", str(preds or case["preds"]), "--data", str(case["root"]),
            "--split", str(case["split"]), "--palette", "uavid", "--output", str(out),
            "--no-progress", *extra]  # fmt: skip


def test_per_image_and_per_bin_miou_by_hand(case, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(_args(case, out, "--bins", "2")) == 0
    report = json.loads((out / "report.json").read_text())
    confs = [_by_hand(t, p) for t, p in zip(case["truths"], case["predictions"], strict=True)]

    perfect, zeros, shifted = (report["images"][i] for i in range(3))
    assert [r["path"] for r in report["images"]] == case["paths"]
    assert perfect["miou"] == 1.0 and perfect["pixel_acc"] == 1.0
    # All class 0: IoU(0) = n0 / valid pixels; every other class present in the truth: 0.
    truth = case["truths"][1]
    valid = truth[truth != 255]
    present = set(np.unique(valid).tolist()) | {0}
    assert zeros["miou"] == pytest.approx(np.mean(valid == 0) / len(present))
    assert zeros["pixel_acc"] == pytest.approx(np.mean(valid == 0))
    assert shifted["miou"] == 0.0 and shifted["pixel_acc"] == 0.0
    for row, value in zip(report["images"], case["delent"], strict=True):
        assert row["delent"] == pytest.approx(value, abs=1e-12)

    # Two quantile bins over 3 images: the 2 lowest delentropies, then the highest; each
    # bin's mIoU from its summed confusion.
    order = np.argsort(case["delent"])
    low, high = report["bins"]
    assert (low["num_images"], high["num_images"]) == (2, 1)
    assert low["miou"] == pytest.approx(_miou(confs[order[0]] + confs[order[1]]))
    assert high["miou"] == pytest.approx(_miou(confs[order[2]]))
    assert low["lo"] == pytest.approx(case["delent"][order[0]])
    assert high["hi"] == pytest.approx(case["delent"][order[2]])
    total = sum(confs)
    assert report["overall"]["miou"] == pytest.approx(_miou(total))
    assert report["overall"]["pixel_acc"] == pytest.approx(np.trace(total) / total.sum())
    assert report["palette"] == "uavid" and report["ignore_index"] == 255
    assert set(report) == {"overall", "bins", "groups", "images", "correlation", "classes",
                           "palette", "ignore_index", "convention", "source",
                           "uncertainty", "quality"}  # fmt: skip
    assert report["correlation"]["delent"]["n"] == 3
    printed = capsys.readouterr().out
    assert "low" in printed and "report.md" in printed
    assert "summed confusion" in (out / "report.md").read_text()
    with np.load(out / "confusions.npz") as saved:
        np.testing.assert_array_equal(saved["confusions"], np.stack(confs))


def test_fixed_edges_with_an_empty_bin_and_one_outside(case, tmp_path):
    d = sorted(case["delent"])
    edges = [d[0], (d[0] + d[1]) / 2, d[1] - 1e-9, d[1] + 1e-9]  # d[2] is above the last edge
    out = tmp_path / "rep"
    assert main(_args(case, out, "--edges", ",".join(repr(e) for e in edges))) == 0
    report = json.loads((out / "report.json").read_text())
    assert [b["num_images"] for b in report["bins"]] == [1, 0, 1]
    assert report["bins"][1]["miou"] is None
    assert report["bins"][1]["lo"] == pytest.approx(edges[1])
    assert report["source"]["binning"]["outside"] == [case["paths"][int(np.argmax(case["delent"]))]]


def _error_line(capsys):
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("claravid-eval: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def _damaged(case, tmp_path, key_index, image):
    preds = tmp_path / "preds"
    shutil.copytree(case["preds"], preds)
    target = preds / f"{FRAMES[key_index]}.png"
    if image is None:
        target.unlink()
    else:
        cv2.imwrite(str(target), image)
    return preds, target


def test_missing_predictions_fail_with_count_and_paths(case, tmp_path, capsys):
    preds, target = _damaged(case, tmp_path, 1, None)
    assert main(_args(case, tmp_path / "rep", preds=preds)) == 2
    line = _error_line(capsys)
    assert "1 prediction(s) missing" in line and str(target) in line
    assert "--allow-missing" in line
    assert not (tmp_path / "rep" / "report.json").exists()


def test_allow_missing_skips_and_reports_them(case, tmp_path, capsys):
    preds, _ = _damaged(case, tmp_path, 1, None)
    out = tmp_path / "rep"
    assert main(_args(case, out, "--bins", "2", "--allow-missing", preds=preds)) == 1
    report = json.loads((out / "report.json").read_text())
    assert report["overall"]["num_images"] == 2
    assert report["source"]["skipped"] == [case["paths"][1]]
    assert case["paths"][1] in capsys.readouterr().err


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (
            lambda t: np.zeros((t.shape[0], t.shape[1] + 1), np.uint8),
            "65×48 but its image is 64×48",
        ),
        (lambda t: np.zeros((*t.shape, 3), np.uint8), "3 channels"),
        (lambda t: np.zeros(t.shape, np.uint16), "uint16"),
        (lambda t: np.full(t.shape, 9, np.uint8), "ids [9] outside the palette's 8 classes"),
    ],
    ids=["size", "channels", "dtype", "ids"],
)
def test_bad_prediction_files_are_named(case, tmp_path, capsys, make, expected):
    h, w = case["truths"][0].shape
    assert (w, h) == (64, 48)
    image = make(case["truths"][0])
    preds, target = _damaged(case, tmp_path, 0, image)
    assert main(_args(case, tmp_path / "rep", preds=preds)) == 2
    line = _error_line(capsys)
    assert str(target) in line and expected in line


@pytest.mark.parametrize(
    ("corrupt", "expected"),
    [
        # JPEG bytes under a .png name decode to ids that are wrong along every edge.
        (lambda png, truth: cv2.imencode(".jpg", truth)[1].tobytes(), "holds JPEG data"),
        (lambda png, truth: png[: len(png) // 2], "truncated PNG"),
        (lambda png, truth: b"", "empty"),
    ],
    ids=["jpeg-as-png", "truncated", "empty"],
)
def test_undecodable_prediction_files_are_named(case, tmp_path, capsys, corrupt, expected):
    preds, target = _damaged(case, tmp_path, 0, case["truths"][0])
    target.write_bytes(corrupt(target.read_bytes(), case["truths"][0]))
    assert main(_args(case, tmp_path / "rep", preds=preds)) == 2
    line = _error_line(capsys)
    assert str(target) in line and expected in line


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--bins", "4"], "4 bins for 3 images"),
        (["--edges", "5,4.5,6"], "strictly increasing"),
        (["--onnx", "x.onnx"], "argument --onnx: not allowed with argument --predictions"),
        (["--bins", "2", "--edges", "1,2"], "--bins or --edges"),
        (["--measures", "delent,nope"], "unknown measure"),
    ],
)
def test_user_mistakes_exit_2_with_one_line(case, tmp_path, capsys, extra, expected):
    assert main(_args(case, tmp_path / "rep", *extra)) == 2
    assert expected in _error_line(capsys)


def test_no_source_at_all(tmp_path, capsys):
    assert main(["--data", str(tmp_path), "--output", str(tmp_path / "o")]) == 2
    assert "one of the arguments --checkpoint --onnx --predictions is required" in _error_line(
        capsys
    )


def test_output_folder_of_someone_else_is_refused(case, tmp_path, capsys):
    out = tmp_path / "theirs"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main(_args(case, out)) == 2
    assert "--overwrite" in _error_line(capsys)
    assert main(_args(case, out, "--overwrite")) == 0
    assert (out / "notes.txt").read_text() == "keep me"


def test_unreadable_image_is_named(case, writable_root, tmp_path, capsys):
    rgb = writable_root / "003_urban_1" / "left_rgb" / "55deg_mid_v" / "000001.jpg"
    rgb.write_bytes(rgb.read_bytes()[:200])  # truncated JPEG
    argv = _args(case, tmp_path / "rep")
    argv[argv.index("--data") + 1] = str(writable_root)
    assert main(argv) == 2
    assert str(rgb) in _error_line(capsys)

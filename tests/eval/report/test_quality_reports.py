"""The measures beyond mIoU across saved reports: parts merge into one run's sums (a pair split
across parts counted once), a comparison finds the model with the worse boundaries per bin, and
reports written before these measures (the schema of docs/report-format.md before them, written
here by hand) still read, merge and compare, their new measures marked absent."""

from __future__ import annotations

import json
import subprocess

import cv2
import numpy as np
import pytest

from claravid.eval.cli.evaluate import main
from claravid.eval.report.files import load_result
from tests.helpers.torchrun import torchrun
from tests.tiny import WINDOW

# Frames of the tiny tree: rural_1/45deg_low_h/000001 -> 000002 and urban_1/55deg_mid_h/000000
# -> 000001 are pairs with overlap; the first is split between the two parts.
PART0 = ["001_rural_1/45deg_low_h/000000", "001_rural_1/45deg_low_h/000001"]
PART1 = ["001_rural_1/45deg_low_h/000002", "003_urban_1/55deg_mid_h/000000",
         "003_urban_1/55deg_mid_h/000001", "003_urban_1/55deg_mid_h/000002"]  # fmt: skip
QUALITY_ARRAYS = ("boundary_sums", "calibration_sums", "pair_sums", "pair_status", "pair_next")


def _split(tmp, name, frames):
    path = tmp / f"{name}.txt"
    path.write_text("\n".join(frames) + "\n")
    return str(path)


def test_merged_parts_equal_one_run_for_every_sum(model_files, tmp_path):
    common = ["--checkpoint", str(model_files["checkpoint"]), "--window", WINDOW, "--bins", "2",
              "--no-progress", "--bootstrap", "100"]  # fmt: skip
    for name, frames in (("p0", PART0), ("p1", PART1), ("whole", PART0 + PART1)):
        split = _split(tmp_path, name, frames)
        assert main([*common, "--split", split, "--output", str(tmp_path / name)]) == 0
    assert main(["merge", str(tmp_path / "p0"), str(tmp_path / "p1"), "--bins", "2",
                 "--bootstrap", "100", "--output", str(tmp_path / "merged")]) == 0  # fmt: skip
    with (
        np.load(tmp_path / "merged" / "confusions.npz") as merged,
        np.load(tmp_path / "whole" / "confusions.npz") as whole,
    ):
        for name in QUALITY_ARRAYS:
            np.testing.assert_array_equal(merged[name], whole[name], err_msg=name)
        status = whole["pair_status"].tolist()
        # The pair split across the parts is counted (by part 0, which predicted 000002).
        assert status[1] == "ok" and status.count("ok") == 2, status
    merged = json.loads((tmp_path / "merged" / "report.json").read_text())
    whole = json.loads((tmp_path / "whole" / "report.json").read_text())
    for key in ("overall", "bins", "images", "quality"):
        assert merged[key] == whole[key], key


def _band(mask: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of a class edge (where Boundary IoU looks)."""
    square = np.ones((3, 3), np.uint8)
    edge = cv2.morphologyEx(mask, cv2.MORPH_GRADIENT, square) > 0
    return cv2.dilate(edge.astype(np.uint8), square) > 0


def test_compare_finds_worse_boundaries_per_bin(label_map_reports, tmp_path):
    ds, common = label_map_reports["ds"], label_map_reports["common"]
    rng = np.random.default_rng(0)
    for i, frame in enumerate(ds.frames):
        truth = ds.read_mask(i)
        valid = np.where(truth == 255, 0, truth).astype(np.uint8)
        band = _band(valid)
        inner = np.flatnonzero(~band)
        wrong = {"edges": band.ravel().copy(), "inside": np.zeros(truth.size, bool)}
        # As many wrong pixels inside the regions as on their edges: the same pixel accuracy.
        wrong["inside"][rng.choice(inner, min(len(inner), int(band.sum())), replace=False)] = True
        for name, where in wrong.items():
            pred = np.where(where.reshape(truth.shape), (valid + 1) % 8, valid).astype(np.uint8)
            (tmp_path / name / frame.key).parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(tmp_path / name / f"{frame.key}.png"), pred)
    for name in ("inside", "edges"):
        argv = ["--predictions", str(tmp_path / name), *common, "--output",
                str(tmp_path / f"rep_{name}")]  # fmt: skip
        assert main(argv) == 0
    out = tmp_path / "cmp"
    assert main(["compare", str(tmp_path / "rep_inside"), str(tmp_path / "rep_edges"),
                 "--bootstrap", "100", "--output", str(out)]) == 0  # fmt: skip
    comparison = json.loads((out / "compare.json").read_text())["comparisons"][0]
    boundary = comparison["quality"]["boundary_iou"]
    assert [b["name"] for b in boundary["bins"]] == ["low", "medium", "high"]
    for row in [*boundary["bins"], boundary["overall"]]:
        gap = row["miou"]
        assert gap["paired"] and gap["gap"] < 0 and gap["gap_ci"][1] < 0, row
    assert set(comparison["missing"]) == {"calibration"}  # label maps: no scores in either
    text = (out / "compare.md").read_text()
    table = text.split("Boundary IoU: rep_edges − rep_inside, paired:")[1].split("\n\n")[1]
    assert table.count("**excludes 0**") == 4, table  # 3 bins and overall
    assert "Calibration not compared: unavailable in rep_inside" in text


def _old_schema(new_folder, old_folder):
    """A report folder as claravid-eval wrote it before the measures beyond mIoU, by hand from
    the previous docs/report-format.md: its report.json keys and confusions.npz arrays, the
    numbers taken from ``new_folder``'s per-image confusions."""
    with np.load(new_folder / "confusions.npz") as npz:
        arrays = {k: npz[k] for k in ("paths", "keys", "confusions", "classes", "palette",
                                      "complexity_delent")}  # fmt: skip
        arrays.update({k: npz[k] for k in npz.files if k.startswith("attribute_")})
    new = json.loads((new_folder / "report.json").read_text())
    arrays["report_id"] = np.asarray("0ld0", dtype=str)
    old_folder.mkdir()
    np.savez_compressed(old_folder / "confusions.npz", **arrays)
    metric = ("miou", "pixel_acc", "per_class_iou", "miou_ci", "pixel_acc_ci", "ci_note")
    row_keys = ("name", "num_images", "lo", "hi", *metric)
    report = {
        "overall": {k: new["overall"][k] for k in ("num_images", *metric)},
        "bins": [{k: b[k] for k in row_keys} for b in new["bins"]],
        "groups": [],
        "images": [
            {k: r[k] for k in ("path", "delent", "miou", "pixel_acc")} for r in new["images"]
        ],
        "correlation": new["correlation"],
        "classes": new["classes"],
        "palette": new["palette"],
        "ignore_index": 255,
        "convention": new["convention"],
        "source": {
            "kind": "predictions",
            "predictions": "old-preds",
            "dataset": "claravid",
            "data": new["source"]["data"],
            "split": "all",
            "measures": ["delent"],
            "skipped": [],
            "report_id": "0ld0",
            "binning": {
                "measure": "delent",
                "method": "quantile",
                "bins": 3,
                "outside": [],
                "group_by": None,
            },
        },
        "uncertainty": new["uncertainty"],
    }
    (old_folder / "report.json").write_text(json.dumps(report, indent=2))
    return old_folder


def test_reports_before_the_measures_read_merge_and_compare(label_map_reports, tmp_path):
    tmp = label_map_reports["tmp"]
    old = _old_schema(tmp / "a", tmp_path / "old")
    result = load_result(old)
    assert set(result.quality.status.values()) == {"absent"}
    assert "written before" in result.quality.reasons["boundary_iou"]

    # Re-binned alone: mIoU as before, every new measure marked absent, with the reason.
    assert main(["merge", str(old), "--bins", "2", "--bootstrap", "100",
                 "--output", str(tmp_path / "rebinned")]) == 0  # fmt: skip
    rebinned = json.loads((tmp_path / "rebinned" / "report.json").read_text())
    assert {q["status"] for q in rebinned["quality"].values()} == {"absent"}
    assert "boundary_iou" not in rebinned["overall"]
    text = (tmp_path / "rebinned" / "report.md").read_text()
    assert "- Boundary IoU: absent (the report was written before" in text

    # Merged with a part that has them: the merged report cannot have them either, and says so.
    b = load_result(tmp / "b")
    assert b.quality.status["boundary_iou"] == "computed"
    assert (
        main(
            [
                "merge",
                str(old),
                str(tmp / "b"),
                "--bootstrap",
                "100",
                "--output",
                str(tmp_path / "mixed"),
            ]
        )
        == 2
    )  # the same images: refused
    # Compared with a report that has them: mIoU compared, the rest named as missing.
    out = tmp_path / "cmp"
    assert main(["compare", str(old), str(tmp / "b"), "--bootstrap", "100",
                 "--output", str(out)]) == 0  # fmt: skip
    comparison = json.loads((out / "compare.json").read_text())["comparisons"][0]
    assert comparison["comparable"] and comparison["overall"]["gap"] < 0
    assert comparison["quality"] == {}
    assert set(comparison["missing"]) == {"boundary_iou", "calibration", "consistency"}
    assert "absent in old" in comparison["missing"]["boundary_iou"]
    text = (out / "compare.md").read_text()
    assert "Boundary IoU not compared: absent in old (the report was written before" in text


def test_old_and_new_parts_merge_with_the_new_measures_marked(label_map_reports, tmp_path):
    """Disjoint parts, one written before the measures: the merge keeps mIoU whole and marks
    each new measure as not in every part."""
    tmp, root = label_map_reports["tmp"], label_map_reports["root"]
    split = _split(tmp_path, "p1", PART1)
    argv = ["--predictions", str(tmp / "pred_a"), "--data", str(root), "--split", split,
            "--palette", "uavid", "--no-progress", "--bootstrap", "100", "--bins", "2"]  # fmt: skip
    assert main([*argv, "--output", str(tmp_path / "new")]) == 0
    argv[argv.index(split)] = _split(tmp_path, "p0", PART0)
    assert main([*argv, "--output", str(tmp_path / "first")]) == 0
    old = _old_schema(tmp_path / "first", tmp_path / "old")
    assert main(["merge", str(old), str(tmp_path / "new"), "--bins", "2", "--bootstrap", "100",
                 "--output", str(tmp_path / "merged")]) == 0  # fmt: skip
    merged = json.loads((tmp_path / "merged" / "report.json").read_text())
    assert merged["overall"]["num_images"] == 6
    quality = merged["quality"]["boundary_iou"]
    assert quality["status"] == "unavailable" and "not in every part" in quality["reason"]
    assert "old (absent)" in quality["reason"]


@pytest.mark.slow
def test_torchrun_counts_a_pair_split_across_ranks_once(model_files, tmp_path):
    """Two ranks take contiguous halves: rural_1/45deg_low_h/000001 (rank 0) pairs with
    000002 (rank 1), which rank 0 predicts for that pair; the sums equal one process's."""
    split = _split(tmp_path, "four", [*PART0, *PART1[:2]])
    argv = ["-m", "claravid.eval", "--checkpoint", str(model_files["checkpoint"]), "--split",
            split, "--window", WINDOW, "--no-progress", "--device", "cpu", "--bins", "2",
            "--bootstrap", "100"]  # fmt: skip
    run = subprocess.run([*torchrun(2), *argv, "--output", str(tmp_path / "two")],
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    assert main([*argv[2:], "--output", str(tmp_path / "one")]) == 0
    with (
        np.load(tmp_path / "two" / "confusions.npz") as two,
        np.load(tmp_path / "one" / "confusions.npz") as one,
    ):
        for name in QUALITY_ARRAYS:
            np.testing.assert_array_equal(two[name], one[name], err_msg=name)
        assert one["pair_status"].tolist()[1] == "ok"  # the split pair, counted once
    two = json.loads((tmp_path / "two" / "report.json").read_text())
    one = json.loads((tmp_path / "one" / "report.json").read_text())
    for key in ("overall", "bins", "images", "quality"):
        assert two[key] == one[key], key

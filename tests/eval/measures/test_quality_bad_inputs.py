"""Bad inputs of the measures beyond mIoU: each says what was wrong in one line (exit 2 from the
command line, a clear exception from Python), or, for a partial download, reports the pairs it
cannot measure and changes nothing else."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import claravid.eval as ev
from claravid.eval.cli.evaluate import main
from claravid.infra.cli import UsageError
from claravid.io import modalities

VIEW = "003_urban_1/{m}/55deg_mid_h/{stem}.{ext}"  # its frames 000000 and 000001 overlap


def _one_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if "warning:" not in line]  # fmt: skip
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def _labels(tmp_path, root, ds):
    """Label maps equal to the labels (uavid ids) of every frame of the tree."""
    import cv2

    for i, frame in enumerate(ds.frames):
        truth = ds.read_mask(i)
        (tmp_path / "preds" / frame.key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tmp_path / "preds" / f"{frame.key}.png"),
                    np.where(truth == 255, 0, truth).astype(np.uint8))  # fmt: skip
    return ["--predictions", str(tmp_path / "preds"), "--data", str(root), "--split", "all",
            "--palette", "uavid", "--no-progress", "--bootstrap", "0"]  # fmt: skip


@pytest.fixture
def label_maps(label_map_reports):
    return label_map_reports["tmp"] / "pred_a", label_map_reports["root"]


def test_calibration_of_label_maps_is_refused_in_one_line(label_maps, tmp_path, capsys):
    preds, root = label_maps
    argv = ["--predictions", str(preds), "--data", str(root), "--split", "all", "--palette",
            "uavid", "--calibration", "--output", str(tmp_path / "rep")]  # fmt: skip
    assert main(argv) == 2
    line = _one_line(capsys)
    assert "--calibration" in line and "label maps have no scores" in line
    assert not (tmp_path / "rep").exists()
    with pytest.raises(UsageError, match="label maps have no scores"):
        ev.evaluate(tmp_path / "api", predictions=preds,
                    data=ev.DataChoice(root=root, split="all", palette="uavid"),
                    report=ev.ReportSettings(calibration=True))  # fmt: skip


def test_consistency_without_depth_is_refused_for_other_data(tmp_path, capsys):
    import cv2

    images, masks = tmp_path / "images", tmp_path / "masks"
    for folder in (images, masks):
        folder.mkdir()
    cv2.imwrite(str(images / "x.png"), np.zeros((6, 8, 3), np.uint8))
    cv2.imwrite(str(masks / "x.png"), np.zeros((6, 8), np.uint8))
    cv2.imwrite(str(tmp_path / "x.png"), np.zeros((6, 8), np.uint8))
    argv = ["--predictions", str(tmp_path), "--dataset", "folder", "--data", str(images),
            "--masks", str(masks), "--palette", "udd6", "--bins", "1", "--consistency",
            "--output", str(tmp_path / "rep")]  # fmt: skip
    assert main(argv) == 2
    assert "--consistency cannot be computed: a folder of images has no depth" in _one_line(capsys)


@pytest.mark.parametrize("flag", ["--no-boundary", "--calibration", "--consistency"])
def test_measure_flags_do_nothing_with_merge_or_compare(label_map_reports, flag, capsys):
    a = str(label_map_reports["tmp"] / "a")
    assert main(["compare", a, a, flag]) == 2
    # compare's parser has no measure flags: its reports carry their own measures
    assert f"unrecognized arguments: {flag}" in _one_line(capsys)


def test_settings_refuse_a_non_boolean():
    with pytest.raises(ValueError, match="boundary must be True, False or None"):
        ev.ReportSettings(boundary="yes")


def test_measures_switched_off_are_marked_off(label_maps, tmp_path):
    preds, root = label_maps
    argv = ["--predictions", str(preds), "--data", str(root), "--split", "all", "--palette",
            "uavid", "--no-progress", "--bootstrap", "0", "--no-boundary", "--no-consistency",
            "--output", str(tmp_path / "rep")]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert report["quality"]["boundary_iou"]["status"] == "off"
    assert report["quality"]["consistency"]["status"] == "off"
    assert "boundary_iou" not in report["overall"] and "consistency" not in report["images"][0]
    with np.load(tmp_path / "rep" / "confusions.npz") as npz:
        assert "boundary_sums" not in npz.files and "pair_sums" not in npz.files


def test_partial_download_makes_pairs_unavailable_and_changes_nothing_else(writable_root, tmp_path):
    from claravid.data.segmentation import ClaraVidSegmentation

    ds = ClaraVidSegmentation(writable_root, split="all", palette="uavid")
    argv = _labels(tmp_path, writable_root, ds)
    assert main([*argv, "--output", str(tmp_path / "full")]) == 0
    shutil.rmtree(writable_root / "003_urban_1" / "depth")  # one mission without depth
    assert main([*argv, "--output", str(tmp_path / "part")]) == 0
    full = json.loads((tmp_path / "full" / "report.json").read_text())
    part = json.loads((tmp_path / "part" / "report.json").read_text())
    assert part["overall"]["miou"] == full["overall"]["miou"]
    assert part["overall"]["boundary_iou"] == full["overall"]["boundary_iou"]
    pairs = part["quality"]["consistency"]["pairs"]
    assert pairs["unavailable"] == 12 and pairs["ok"] + pairs["turn"] + pairs["last"] == 24
    assert "depth" in part["quality"]["consistency"]["unavailable"][0]
    # No depth anywhere: consistency unavailable with the reason, the run goes on (exit 0).
    shutil.rmtree(writable_root / "001_rural_1" / "depth")
    assert main([*argv, "--output", str(tmp_path / "none")]) == 0
    none = json.loads((tmp_path / "none" / "report.json").read_text())
    assert none["quality"]["consistency"]["status"] == "unavailable"
    assert "no depth/ folder" in none["quality"]["consistency"]["reason"]
    assert none["overall"]["miou"] == full["overall"]["miou"]


def test_a_pose_that_is_not_rigid_is_refused_naming_the_file(writable_root, tmp_path, capsys):
    from claravid.data.segmentation import ClaraVidSegmentation

    ds = ClaraVidSegmentation(writable_root, split="all", palette="uavid")
    argv = _labels(tmp_path, writable_root, ds)
    pose_file = writable_root / VIEW.format(m="extrinsics", stem="000001", ext="json")
    pose = modalities.read_extrinsics(pose_file).astype(np.float64)
    pose[:3, :3] *= 1.5  # scaled: not a rigid transform
    pose_file.write_text(json.dumps(pose.tolist()))
    assert main([*argv, "--output", str(tmp_path / "rep")]) == 2
    line = _one_line(capsys)
    assert str(pose_file) in line and "rigid" in line


def test_identical_poses_are_flagged_and_left_out(writable_root, tmp_path):
    from claravid.data.segmentation import ClaraVidSegmentation

    ds = ClaraVidSegmentation(writable_root, split="all", palette="uavid")
    argv = _labels(tmp_path, writable_root, ds)
    first = writable_root / VIEW.format(m="extrinsics", stem="000000", ext="json")
    shutil.copy(first, writable_root / VIEW.format(m="extrinsics", stem="000001", ext="json"))
    assert main([*argv, "--output", str(tmp_path / "rep")]) == 0
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    summary = report["quality"]["consistency"]
    assert summary["pairs"]["identical_poses"] == 1
    assert any("identical poses" in reason for reason in summary["unavailable"])
    text = (tmp_path / "rep" / "report.md").read_text()
    assert "1 identical poses" in text

"""The report records the ClaraVid frames it used; --missions/--altitude/--direction override
the checkpoint's selection."""

import json

import pytest
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.cli.evaluate import main


def _report(folder):
    return json.loads((folder / "report.json").read_text())


def _run(argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors
        return exc.code


@pytest.fixture(scope="module")
def rural_checkpoint(model_files, tmp_path_factory):
    """The tiny checkpoint, its training config restricted to rural_1 at low and high altitude."""
    ckpt = torch.load(model_files["checkpoint"], map_location="cpu", weights_only=False)
    ckpt["config"]["data"].update(missions=["rural_1"], altitude=["low", "high"])
    path = tmp_path_factory.mktemp("sel") / "rural.pt"
    torch.save(ckpt, path)
    return path


def test_report_records_the_checkpoint_selection(rural_checkpoint, claravid_root, tmp_path):
    argv = ["--checkpoint", str(rural_checkpoint), "--split", "all", "--bootstrap", "0",
            "--no-progress", "--output", str(tmp_path / "r")]  # fmt: skip
    assert _run(argv) == 0
    report = _report(tmp_path / "r")
    chosen = report["source"]["selection"]
    assert chosen["missions"] == ["rural_1"] and chosen["altitude"] == ["low", "high"]
    assert chosen["direction"] is None and chosen["split_config"]["block_size"] == 150.0
    expected = ClaraVidSegmentation(claravid_root, split="all", missions=["rural_1"],
                                    altitude=["low", "high"])  # fmt: skip
    assert sorted(r["path"] for r in report["images"]) == sorted(
        str(f.paths["rgb"]) for f in expected.frames
    )
    assert "missions rural_1; altitude low, high" in (tmp_path / "r" / "report.md").read_text()


def test_flags_override_the_checkpoint_selection(rural_checkpoint, claravid_root, tmp_path):
    argv = ["--checkpoint", str(rural_checkpoint), "--split", "all", "--bootstrap", "0",
            "--no-progress", "--missions", "urban_1", "--altitude", "high", "--direction", "v",
            "--output", str(tmp_path / "u")]  # fmt: skip
    assert _run(argv) == 0
    report = _report(tmp_path / "u")
    chosen = report["source"]["selection"]
    assert (chosen["missions"], chosen["altitude"], chosen["direction"]) == (
        ["urban_1"], ["high"], ["v"])  # fmt: skip
    expected = ClaraVidSegmentation(claravid_root, split="all", missions=["urban_1"],
                                    altitude="high", direction="v")  # fmt: skip
    assert len(report["images"]) == len(expected) > 0
    assert all("urban_1" in r["path"] and "high_v" in r["path"] for r in report["images"])


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--missions", "nowhere_9"], "unknown ClaraVid mission"),
        (["--missions", ","], "--missions is empty"),
        (["--altitude", "space"], "altitude"),
        (["--dataset", "uavid", "--direction", "h"], "--direction selects ClaraVid frames"),
    ],
)
def test_bad_selection(model_files, claravid_root, tmp_path, capsys, extra, message):
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--data", str(claravid_root),
            "--no-progress", *extra, "--output", str(tmp_path / "bad")]  # fmt: skip
    assert _run(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad" / "report.json").exists()


def test_selection_flags_do_nothing_with_merge(tmp_path, capsys):
    assert (
        _run(["merge", str(tmp_path), "--missions", "rural_1", "--output", str(tmp_path / "m")])
        == 2
    )
    assert "unrecognized arguments: --missions rural_1" in capsys.readouterr().err

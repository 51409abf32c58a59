"""Backbone comparison, the use case of DINOv3 support: a DINOv2 and a DINOv3 model trained on
the same split, each validated per complexity bin, evaluated, then compared image by image."""

import json

import pytest

from claravid.eval.cli.evaluate import main as eval_main
from claravid.models.checkpoint import read_checkpoint


@pytest.mark.slow
def test_a_dinov2_and_a_dinov3_model_compare_paired_per_bin(
    trained_v2, trained_sat, tmp_path, capsys
):
    """The session's tiny runs: dinov2_vits14 and dinov3_vitl16_sat on the same split."""
    reports = {}
    for name, run in {"dinov2": trained_v2, "dinov3": trained_sat}.items():
        result = run["result"]
        # Validated per delentropy bin of the val images (3 quantile bins, val.bins).
        assert list(result.last_val["miou_bins"]) == ["low", "medium", "high"], name
        assert all(0 <= v <= 1 for v in result.last_val["miou_bins"].values())
        ckpt = run["ckpt"]
        assert read_checkpoint(ckpt)["config"]["data"]["val_split"] == "test"
        out = tmp_path / f"report_{name}"
        # The checkpoint's own split (the same test frames for both): 2 quantile bins.
        argv = ["--checkpoint", str(ckpt), "--split", "test", "--bins", "2", "--hardest", "0",
                "--bootstrap", "200", "--output", str(out), "--no-progress"]  # fmt: skip
        assert eval_main(argv) == 0
        reports[name] = json.loads((out / "report.json").read_text())
    a, b = reports["dinov2"], reports["dinov3"]
    assert [r["source"]["settings"]["window"] for r in (a, b)] == [[28, 28], [32, 32]]
    assert [i["path"] for i in a["images"]] == [i["path"] for i in b["images"]]
    cmp = tmp_path / "cmp"
    argv = ["compare", str(tmp_path / "report_dinov2" / "report.json"),
            str(tmp_path / "report_dinov3" / "report.json"), "--bootstrap", "200",
            "--output", str(cmp)]  # fmt: skip
    assert eval_main(argv) == 0
    (entry,) = json.loads((cmp / "compare.json").read_text())["comparisons"]
    # Paired (the same images), overall and in each bin; each gap is B − A of the reports'.
    assert entry["paired"] is True and entry["overall"]["paired"] is True
    gap = b["overall"]["miou"] - a["overall"]["miou"]
    assert entry["overall"]["gap"] == pytest.approx(gap, abs=1e-9)
    assert len(entry["bins"]) == len(a["bins"]) == len(b["bins"]) == 2
    for row, bin_a, bin_b in zip(entry["bins"], a["bins"], b["bins"], strict=True):
        assert row["name"] == bin_a["name"] == bin_b["name"] and row["paired"] is True
        assert row["gap"] == pytest.approx(bin_b["miou"] - bin_a["miou"], abs=1e-9)
        lo, hi = row["gap_ci"] if row["gap_ci"] is not None else (row["gap"], row["gap"])
        assert lo <= row["gap"] <= hi
    assert "compare.md" in capsys.readouterr().out

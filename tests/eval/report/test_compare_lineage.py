"""``compare``: "not comparable" is one run against itself, never two runs that agree (issue 24
§1 item 1), through the command line, :func:`claravid.eval.compare` and ``compare_reports``.

One run seen twice is a report and its own re-binning or merge: the same ``report_id`` lineage.
Two runs whose label maps agree everywhere (a checkpoint and its saved label maps, two exports
of one model, a copy of the label maps) are two runs: a paired gap of exactly 0, interval
[0, 0], p = 1.
"""

import contextlib
import json
import shutil

import pytest

import claravid.eval as ev
from claravid.eval.cli.evaluate import main
from claravid.eval.report.compare import compare_reports


def _cli(reports, out):
    assert main(["compare", *map(str, reports), "--bootstrap", "100", "-o", str(out)]) == 0
    return json.loads((out / "compare.json").read_text())["comparisons"]


def _api(reports, out):
    ev.compare(reports, out, ev.Bootstrap(resamples=100))
    return json.loads((out / "compare.json").read_text())["comparisons"]


def _report_level(reports, out):
    compare_reports(reports, out, ev.Bootstrap(resamples=100))
    return json.loads((out / "compare.json").read_text())["comparisons"]


ENTRY_POINTS = {"cli": _cli, "api": _api, "compare_reports": _report_level}


def _agree(comp, bins=3):
    """A comparable, paired gap of exactly 0 with interval [0, 0] and p = 1, overall and in
    every bin."""
    assert comp.get("comparable", True) is True and "reason" not in comp, comp
    assert comp["paired"] is True
    rows = [comp["overall"], *comp["bins"]]
    assert len(rows) == 1 + bins
    for row in rows:
        assert row["paired"] is True
        assert (row["gap"], row["gap_ci"], row["p_value"]) == (0.0, [0.0, 0.0], 1.0), row


def _one_run(comp):
    assert comp["comparable"] is False and "one run" in comp["reason"], comp
    assert comp["overall"] is None and comp["bins"] == []


@pytest.mark.parametrize("entry", ENTRY_POINTS)
def test_two_runs_that_agree_get_a_gap_of_zero(label_map_reports, tmp_path, entry):
    """``a_again`` scores a copy of ``a``'s label maps in another folder: another run, whose
    confusions equal ``a``'s image by image."""
    tmp = label_map_reports["tmp"]
    (same, worse) = ENTRY_POINTS[entry]([tmp / "a", tmp / "a_again", tmp / "b"], tmp_path / "c")
    _agree(same)
    assert worse["comparable"] is True and worse["overall"]["gap"] < 0  # B is worse
    text = (tmp_path / "c" / "compare.md").read_text()
    assert "not comparable" not in text


@pytest.fixture(scope="module")
def lineage(label_map_reports, tmp_path_factory):
    """Reports made from ``a``: re-binned, re-binned again, copied; and ``a``'s label maps
    evaluated in two parts of 6 frames each, and their merge."""
    reps, tmp = label_map_reports, label_map_reports["tmp"]
    out = tmp_path_factory.mktemp("lineage")
    rebinned, twice = out / "a5", out / "a2"
    assert main(["merge", str(tmp / "a"), "--bins", "5", "-o", str(rebinned)]) == 0
    assert main(["merge", str(rebinned), "--bins", "2", "-o", str(twice)]) == 0
    copy = shutil.copytree(tmp / "a", out / "copy")  # the same report_id
    # Parts of one split evaluated apart and merged: the merge is one run with each part.
    parts = []
    for k in (0, 1):
        listing = out / f"part{k}.txt"
        listing.write_text("\n".join(f.key for f in reps["ds"].frames[k:12:2]) + "\n")
        common = [str(listing) if a == "all" else a for a in reps["common"]]
        argv = ["--predictions", str(tmp / "pred_a"), *common, "--cluster", "image", "-o",
                str(out / f"p{k}")]  # fmt: skip
        assert main(argv) == 0
        parts.append(out / f"p{k}")
    merged = out / "merged"
    assert main(["merge", *map(str, parts), "--cluster", "image", "-o", str(merged)]) == 0
    # The same 12 frames evaluated in one run: another run than the merge of its parts.
    listing = out / "twelve.txt"
    listing.write_text("\n".join(f.key for f in reps["ds"].frames[:12]) + "\n")
    common = [str(listing) if a == "all" else a for a in reps["common"]]
    argv = ["--predictions", str(tmp / "pred_a"), *common, "--cluster", "image", "-o",
            str(out / "whole")]  # fmt: skip
    assert main(argv) == 0
    return {"a": tmp / "a", "rebinned": rebinned, "twice": twice, "copy": copy,
            "parts": parts, "merged": merged, "whole": out / "whole"}  # fmt: skip


@pytest.mark.parametrize("entry", ENTRY_POINTS)
def test_a_report_and_its_own_rebinning_or_merge_are_one_run(lineage, tmp_path, entry):
    compare = ENTRY_POINTS[entry]
    # Re-binned reports cover other delentropy ranges: the API warns (the command prints it).
    with (
        pytest.warns(UserWarning, match="bin edges differ")
        if entry == "api"
        else contextlib.nullcontext()
    ):
        _one_run_everywhere(compare, lineage, tmp_path)


def _one_run_everywhere(compare, lineage, tmp_path):
    runs = [lineage[k] for k in ("a", "rebinned", "twice", "copy")]
    for comp in compare(runs, tmp_path / "c1"):
        _one_run(comp)
    for comp in compare([lineage["rebinned"], lineage["twice"]], tmp_path / "c2"):
        _one_run(comp)  # two re-binnings of one report
    (part,) = compare([lineage["merged"], lineage["parts"][0]], tmp_path / "c3")
    _one_run(part)
    # One run over the 12 frames is another run than the merge of its parts, and agrees with
    # it everywhere.
    (whole,) = compare([lineage["whole"], lineage["merged"]], tmp_path / "c4")
    _agree(whole)


def test_a_checkpoint_and_its_saved_label_maps_agree(model_files, claravid_root, tmp_path):
    """The label maps a model evaluation saved, evaluated again: another run with the same
    confusions, so a gap of 0 (not "a model against itself")."""
    frames = tmp_path / "six.txt"
    frames.write_text("".join(f"{m}/{v}/000000\n" for m in ("001_rural_1", "003_urban_1")
                              for v in ("45deg_low_h", "55deg_mid_v", "90deg_high_h")))  # fmt: skip
    preds = tmp_path / "preds"
    common = ["--split", str(frames), "--bins", "2", "--cluster", "image", "--bootstrap", "100",
              "--no-progress"]  # fmt: skip
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--window", "56x42", *common,
            "--save-predictions", str(preds), "-o", str(tmp_path / "model")]  # fmt: skip
    assert main(argv) == 0
    argv = ["--predictions", str(preds), "--data", str(claravid_root), *common, "-o",
            str(tmp_path / "maps")]  # fmt: skip
    assert main(argv) == 0
    (comp,) = _cli([tmp_path / "model", tmp_path / "maps"], tmp_path / "c")
    _agree(comp, bins=2)

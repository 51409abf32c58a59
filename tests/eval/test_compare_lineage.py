"""``--compare``: "not comparable" is one run against itself, never two runs that agree (issue 24
§1 item 1), through the command line, :func:`claravid.eval.compare` and ``compare_reports``.

One run seen twice is a report and its own re-binning or merge: the same ``report_id`` lineage.
Two runs whose label maps agree everywhere (a checkpoint and its saved label maps, two exports
of one model, a copy of the label maps) are two runs: a paired gap of exactly 0, interval
[0, 0], p = 1.
"""

import json
import shutil

import pytest

import claravid.eval as ev
from claravid.eval.cli import main
from claravid.eval.report.compare import compare_reports


def _cli(reports, out):
    assert main(["--compare", *map(str, reports), "--bootstrap", "100", "-o", str(out)]) == 0
    return json.loads((out / "compare.json").read_text())["comparisons"]


def _api(reports, out):
    ev.compare(reports, out, ev.Bootstrap(resamples=100))
    return json.loads((out / "compare.json").read_text())["comparisons"]


def _report_level(reports, out):
    compare_reports(reports, out, ev.Bootstrap(resamples=100))
    return json.loads((out / "compare.json").read_text())["comparisons"]


ENTRY_POINTS = {"cli": _cli, "api": _api, "compare_reports": _report_level}


def _agree(comp):
    """A comparable, paired gap of exactly 0 with interval [0, 0] and p = 1, overall and in
    every bin."""
    assert comp.get("comparable", True) is True and "reason" not in comp, comp
    assert comp["paired"] is True
    rows = [comp["overall"], *comp["bins"]]
    assert len(rows) == 4  # overall and the 3 quantile bins
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


@pytest.mark.parametrize("entry", ENTRY_POINTS)
def test_a_report_and_its_own_rebinning_or_merge_are_one_run(label_map_reports, tmp_path, entry):
    tmp, reps = label_map_reports["tmp"], label_map_reports
    rebinned, twice = tmp_path / "a5", tmp_path / "a2"
    assert main(["--merge", str(tmp / "a"), "--bins", "5", "-o", str(rebinned)]) == 0
    assert main(["--merge", str(rebinned), "--bins", "2", "-o", str(twice)]) == 0
    copy = shutil.copytree(tmp / "a", tmp_path / "copy")  # the same report_id
    # Parts of one split evaluated apart and merged: the merge is one run with each part.
    parts = []
    for k in (0, 1):
        listing = tmp_path / f"part{k}.txt"
        listing.write_text("\n".join(f.key for f in reps["ds"].frames[k::2]) + "\n")
        common = [str(listing) if a == "all" else a for a in reps["common"]]
        argv = ["--predictions", str(tmp / "pred_a"), *common, "-o", str(tmp_path / f"p{k}")]
        assert main(argv) == 0
        parts.append(tmp_path / f"p{k}")
    merged = tmp_path / "merged"
    assert main(["--merge", *map(str, parts), "-o", str(merged)]) == 0
    compare = ENTRY_POINTS[entry]
    for comp in compare([tmp / "a", rebinned, twice, copy], tmp_path / "c1"):
        _one_run(comp)
    for comp in compare([rebinned, twice], tmp_path / "c2"):  # two re-binnings of one report
        _one_run(comp)
    (part,) = compare([merged, parts[0]], tmp_path / "c3")
    _one_run(part)
    # The merge of A's parts is another run than A itself, and agrees with it everywhere.
    (whole,) = compare([tmp / "a", merged], tmp_path / "c4")
    _agree(whole)


def test_a_checkpoint_and_its_saved_label_maps_agree(model_files, claravid_root, tmp_path):
    """The label maps a model evaluation saved, evaluated again: another run with the same
    confusions, so a gap of 0 (not "a model against itself")."""
    preds = tmp_path / "preds"
    common = ["--split", "all", "--bootstrap", "100", "--no-progress"]
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--window", "56x42", *common,
            "--save-predictions", str(preds), "-o", str(tmp_path / "model")]  # fmt: skip
    assert main(argv) == 0
    argv = ["--predictions", str(preds), "--data", str(claravid_root), *common, "-o",
            str(tmp_path / "maps")]  # fmt: skip
    assert main(argv) == 0
    (comp,) = _cli([tmp_path / "model", tmp_path / "maps"], tmp_path / "c")
    _agree(comp)

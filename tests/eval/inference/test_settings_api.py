"""The Python API is as strict as the command line (issue 24 §3, §4): settings are checked when
they are made, with the messages ``claravid-eval`` prints, and wrong arguments are clear
exceptions instead of a ``KeyError`` after the inference or an evaluation of other data."""

import json
import os
import shutil
import warnings

import numpy as np
import pytest

import claravid.eval as ev
from claravid.eval.cli.evaluate import main
from claravid.infra.cli import UsageError

#: (the setting as the Python API makes it, the same mistake on the command line, the message)
MISTAKES = [
    (lambda: ev.DataChoice(dataset="uavd"), ["--dataset", "uavd"], "--dataset 'uavd'"),
    (lambda: ev.DataChoice(selection={"missions": " , "}), ["--missions", " , "],
     "--missions is empty"),
    (lambda: ev.DataChoice(selection={"altitude": ["low", ""]}), ["--altitude", "low,"],
     None),  # a trailing comma is dropped on both sides: no mistake
    (lambda: ev.ReportSettings(group_by="block"), ["--group-by", "block"], "--group-by 'block'"),
    (lambda: ev.ReportSettings(measures=("delent", "entropy")), ["--measures", "delent,entropy"],
     "unknown measure(s) ['entropy']"),
    (lambda: ev.ReportSettings(tiles=31), ["--tiles", "31"], "--tiles must be at least 32"),
    (lambda: ev.ReportSettings(cluster="tile"), ["--cluster", "tile"], "unknown --cluster 'tile'"),
    (lambda: ev.ReportSettings(edges=[5.0, 4.0]), ["--edges", "5,4"], "strictly increasing"),
    (lambda: ev.InferenceSettings(provider="rocm"), ["--provider", "rocm"], "--provider 'rocm'"),
]  # fmt: skip


@pytest.mark.parametrize(("make", "flags", "message"), MISTAKES)
def test_the_api_refuses_what_the_command_line_refuses_with_its_message(
    label_map_reports, tmp_path, capsys, make, flags, message
):
    if message is None:
        make()  # accepted
        return
    with pytest.raises(ValueError) as info:
        make()
    assert message in str(info.value)
    reps = label_map_reports
    source = ["--onnx", str(tmp_path / "m.onnx")] if flags[0] == "--provider" else [
        "--predictions", str(reps["tmp"] / "pred_a"), "--palette", "uavid"]  # fmt: skip
    argv = [*source, "--data", str(reps["root"]), "--split", "all", *flags,
            "-o", str(tmp_path / "o")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"claravid-eval: error: {info.value}"]  # one line, the API's very message
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: ev.ReportSettings(bins=0), "--bins must be at least 1"),
        (lambda: ev.ReportSettings(hardest=-1), "--hardest must be >= 0"),
        (lambda: ev.ReportSettings(bootstrap=1000), "bootstrap must be a Bootstrap"),
        (lambda: ev.InferenceSettings(precision="fp64"), "precision must be one of"),
        (lambda: ev.InferenceSettings(scale=0.0), "--scale must be in (0, 8]"),
        (lambda: ev.InferenceSettings(batch_size=0), "--batch-size must be at least 1"),
        (lambda: ev.InferenceSettings(window=(42, 0)), "--window must be"),
        (lambda: ev.InferenceSettings(stride=-3), "--stride must be"),
        (lambda: ev.DataChoice(selection={"mission": ["rural_1"]}), "unknown selection 'mission'"),
    ],
)
def test_settings_only_the_api_can_get_wrong(make, message):
    # (The command line's own types refuse these before: --bins 0 is argparse's positive_int.)
    with pytest.raises(ValueError) as info:
        make()
    assert message in str(info.value)


def test_measures_without_delent_get_it_first_in_every_entry_point(label_map_reports, tmp_path):
    """``measures=("glcment",)`` once failed with ``KeyError: 'delent'`` after the inference;
    the bins are made of delentropy, so it is always computed first, as --measures does."""
    reps, tmp = label_map_reports, label_map_reports["tmp"]
    settings = ev.ReportSettings(measures=("glcment",), bootstrap=ev.Bootstrap(resamples=0))
    assert settings.measures == ("delent", "glcment")
    data = ev.DataChoice(root=reps["root"], split="all", palette="uavid")
    done = ev.evaluate(tmp_path / "api", predictions=tmp / "pred_a", data=data, report=settings)
    argv = ["--predictions", str(tmp / "pred_a"), *reps["common"][:-2], "--bootstrap", "0",
            "--measures", "glcment", "-o", str(tmp_path / "cli")]  # fmt: skip
    assert main(argv) == 0
    cli = json.loads((tmp_path / "cli" / "report.json").read_text())
    for report in (done.report, cli):
        assert report["source"]["measures"] == ["delent", "glcment"]
        assert list(report["correlation"]) == ["delent", "glcment"]
        assert report["source"]["binning"]["measure"] == "delent"
    assert done.report["bins"] == cli["bins"]
    csv = tmp_path / "s.csv"
    csv.write_text("path,err\n" + "".join(f"{f.paths['rgb']},{i}\n"
                                          for i, f in enumerate(reps["ds"].frames)))  # fmt: skip
    scores = ev.score_metrics(csv, tmp_path / "scores", data=ev.DataChoice(root=reps["root"]),
                              report=settings)  # fmt: skip
    assert scores.report["source"]["binning"]["measure"] == "delent"
    assert list(scores.report["correlation"]) == ["delent", "glcment"]


def test_scores_take_the_data_defaults_of_one_rule(label_map_reports, tmp_path):
    """--scores reads ClaraVid's ``all`` split unless told otherwise, through the same rule as
    an evaluation (``resolve_data``): a selection applies, other data kinds are refused it."""
    reps = label_map_reports
    rural = [f for f in reps["ds"].frames if f.mission == "rural_1"]
    csv = tmp_path / "s.csv"
    csv.write_text("path,err\n" + "".join(f"{f.paths['rgb']},{i}\n" for i, f in enumerate(rural)))
    data = ev.DataChoice(root=reps["root"], selection={"missions": "rural_1"})
    off = ev.ReportSettings(bootstrap=ev.Bootstrap(resamples=0))
    done = ev.score_metrics(csv, tmp_path / "o", data=data, report=off)
    assert done.report["source"]["split"] == "all"
    assert done.report["overall"]["num_images"] == len(rural) == 18
    with pytest.raises(UsageError, match="--missions selects ClaraVid frames"):
        ev.score_metrics(csv, tmp_path / "u", data=ev.DataChoice(
            root=reps["root"], dataset="uavid", selection={"missions": "rural_1"}))  # fmt: skip


# --- §4: wrong arguments are clear exceptions --------------------------------------------------


def test_wrong_arguments_are_clear_exceptions(label_map_reports, tmp_path):
    tmp = label_map_reports["tmp"]
    with pytest.raises(TypeError, match=r"a list of report folders.*\['report'\]"):
        ev.merge("report", tmp_path / "m")
    with pytest.raises(TypeError, match="a list of report folders"):
        ev.merge(tmp / "a", tmp_path / "m")
    with pytest.raises(ValueError, match="at least one report folder to merge"):
        ev.merge([], tmp_path / "m")
    with pytest.raises(TypeError, match="compare takes a list of report folders"):
        ev.compare(str(tmp / "a"), tmp_path / "c")
    with pytest.raises(ValueError, match="at least one report to compare"):
        ev.compare([], tmp_path / "c")
    with pytest.raises(TypeError, match=r"data must be a DataChoice.*DataChoice\(root='root'\)"):
        ev.evaluate(tmp_path / "e", predictions=tmp / "pred_a", data="root")
    with pytest.raises(TypeError, match="report must be a ReportSettings"):
        ev.evaluate(tmp_path / "e", predictions=tmp / "pred_a", report={"bins": 3})
    with pytest.raises(TypeError, match="inference must be an InferenceSettings"):
        ev.evaluate(tmp_path / "e", predictions=tmp / "pred_a", inference="fp32")
    with pytest.raises(TypeError, match="data must be a DataChoice"):
        ev.score_metrics(tmp_path / "s.csv", tmp_path / "s", data=str(tmp))
    with pytest.raises(TypeError, match="settings must be a ReportSettings"):
        ev.merge([tmp / "a"], tmp_path / "m", {"bins": 2})
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize("where", ["confusions", "tile_confusions"])
def test_a_tampered_negative_count_is_refused(label_map_reports, tmp_path, capsys, where):
    """A confusion counts pixels: a negative cell is a damaged or edited file, refused by the
    reader (merge, compare, load_result), one line from the command line."""
    reps, tmp = label_map_reports, label_map_reports["tmp"]
    folder = tmp_path / "t"
    if where == "confusions":
        shutil.copytree(tmp / "a", folder)
    else:  # a tiled report, evaluated here
        argv = ["--predictions", str(tmp / "pred_a"), *reps["common"], "--tiles", "32", "-o",
                str(folder)]  # fmt: skip
        assert main(argv) == 0
    with np.load(folder / "confusions.npz") as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays[where][3, 1, 2] = -5
    arrays[where][3, 1, 1] += 5  # the image's total stays right: only the sign betrays it
    np.savez_compressed(folder / "confusions.npz", **arrays)
    with pytest.raises(UsageError, match="negative"):
        ev.load_result(folder)
    capsys.readouterr()
    for argv in (["merge", str(folder), "-o", str(tmp_path / "m")],
                 ["compare", str(folder), str(tmp / "b")]):  # fmt: skip
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("claravid-eval: error:"), err
        assert "negative" in err[0] and "confusions.npz" in err[0]


# --- §3: one data root spelled two ways is one root ----------------------------------------------


def _parts(reps, tmp_path, roots):
    """Two disjoint sets of 6 frames, evaluated with the data root spelled as ``roots``."""
    parts = []
    for k, root in enumerate(roots):
        listing = tmp_path / f"half{k}.txt"
        listing.write_text("\n".join(f.key for f in reps["ds"].frames[k:12:2]) + "\n")
        argv = ["--predictions", str(reps["tmp"] / "pred_a"), "--data", str(root), "--split",
                str(listing), "--palette", "uavid", "--bootstrap", "0", "--no-progress",
                "-o", str(tmp_path / f"part{k}")]  # fmt: skip
        assert main(argv) == 0
        parts.append(tmp_path / f"part{k}")
    return parts


@pytest.mark.parametrize("spelling", ["dotdot", "symlink", "other"])
def test_merge_warns_of_different_data_roots_only_when_they_differ(
    label_map_reports, tmp_path, capsys, spelling
):
    reps = label_map_reports
    root = reps["root"]
    if spelling == "dotdot":
        other = root / ".." / root.name
    elif spelling == "symlink":
        other = tmp_path / "link"
        os.symlink(root, other)
    else:  # a copy: another data root with the same images' names
        other = shutil.copytree(root, tmp_path / "copy")
    parts = _parts(reps, tmp_path, [root, other])
    capsys.readouterr()
    assert main(["merge", *map(str, parts), "--bootstrap", "0", "-o", str(tmp_path / "m")]) == 0
    cli = "different data roots" in capsys.readouterr().err
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ev.merge(parts, tmp_path / "m2", ev.ReportSettings(bootstrap=ev.Bootstrap(resamples=0)))
    api = any("different data roots" in str(w.message) for w in caught)
    assert cli == api == (spelling == "other")

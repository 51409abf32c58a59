"""Report folders under hostile use (issue 20): replaced whole, files that belong together,
images known by their key, options and inputs that would give a silent wrong number."""

import itertools
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.cli.evaluate import main
from tests.helpers.files import write_noisy_predictions

K = 8  # uavid palette


@pytest.fixture(scope="module")
def reps(claravid_root, tmp_path_factory):
    """Label maps A (10 % wrong) and B (20 % wrong) without predictions.json, their reports."""
    tmp = tmp_path_factory.mktemp("hostile")
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    common = ["--data", str(claravid_root), "--split", "all", "--palette", "uavid",
              "--no-progress", "--bootstrap", "100"]  # fmt: skip
    for name, share in (("a", 0.1), ("b", 0.2)):
        write_noisy_predictions(ds, tmp / f"pred_{name}", share, 0)
        argv = ["--predictions", str(tmp / f"pred_{name}"), *common, "-o", str(tmp / name)]
        assert main(argv) == 0
    return {"tmp": tmp, "common": common, "root": claravid_root}


def _one_line(capsys, *words):
    err = capsys.readouterr().err
    # "claravid-eval: error:", or "claravid-eval merge: error:" from a subcommand's parser
    lines = [ln for ln in err.splitlines()
             if ln.startswith("claravid-eval") and ": error:" in ln]  # fmt: skip
    assert len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def _json(folder):
    return json.loads((folder / "report.json").read_text())


def test_an_interrupted_rewrite_leaves_the_old_folder_whole(reps, tmp_path, monkeypatch):
    """Ctrl-C after the new confusions are written: the old report.json and confusions.npz
    stay together, nothing new beside them, no temp folder left."""
    import claravid.eval.report.folder as folder

    out = shutil.copytree(reps["tmp"] / "a", tmp_path / "rep")
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(folder, "plot_bins", interrupted)
    argv = ["--predictions", str(reps["tmp"] / "pred_b"), *reps["common"], "-o", str(out)]
    assert main(argv) == 130  # "interrupted", as a shell reports Ctrl-C
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]  # no .rep.new-* left
    monkeypatch.undo()
    assert main(argv) == 0  # the full rewrite: new numbers, the user's file kept
    assert _json(out)["overall"]["miou"] == _json(reps["tmp"] / "b")["overall"]["miou"]
    assert (out / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]


def test_confusions_of_another_report_are_refused(reps, tmp_path, capsys):
    out = shutil.copytree(reps["tmp"] / "a", tmp_path / "a")
    shutil.copy(reps["tmp"] / "b" / "confusions.npz", out / "confusions.npz")
    assert main(["merge", str(out), "-o", str(tmp_path / "m")]) == 2
    _one_line(capsys, "does not belong to", "report ids differ")
    assert main(["compare", str(out), str(reps["tmp"] / "b")]) == 2
    _one_line(capsys, "does not belong to")


def test_a_truncated_npz_is_one_line(reps, tmp_path, capsys):
    out = shutil.copytree(reps["tmp"] / "a", tmp_path / "a")
    data = (out / "confusions.npz").read_bytes()
    (out / "confusions.npz").write_bytes(data[: len(data) // 2])
    assert main(["merge", str(out), "-o", str(tmp_path / "m")]) == 2
    _one_line(capsys, "confusions.npz is damaged", "evaluate again")


def test_the_same_images_through_two_spellings_of_the_root(reps, tmp_path, capsys):
    """A symlinked root gives other path strings for the same images: merge refuses them as
    duplicates and compare pairs them (images are known by their key below the root)."""
    link = tmp_path / "link"
    os.symlink(reps["root"], link)
    common = [str(link) if a == str(reps["root"]) else a for a in reps["common"]]
    linked = tmp_path / "b_linked"
    argv = ["--predictions", str(reps["tmp"] / "pred_b"), *common, "-o", str(linked)]
    assert main(argv) == 0
    assert main(["merge", str(reps["tmp"] / "a"), str(linked), "-o", str(tmp_path / "m")]) == 2
    _one_line(capsys, "is in both", "merge disjoint runs")
    out = tmp_path / "cmp"
    assert main(["compare", str(reps["tmp"] / "a"), str(linked), "-o", str(out)]) == 0
    comp = json.loads((out / "compare.json").read_text())["comparisons"][0]
    assert comp["paired"] is True


def test_label_maps_without_a_marker_need_a_palette(reps, capsys, tmp_path):
    argv = ["--predictions", str(reps["tmp"] / "pred_a"), "--data", str(reps["root"]),
            "--split", "all", "-o", str(tmp_path / "x")]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, "--palette", "predictions.json")
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("header", "message"),
    [
        ("path,psnr,psnr", "column 'psnr' appears more than once"),
        ("path,delent", "column 'delent' is named like a complexity measure"),
    ],
)
def test_scores_csv_columns_that_would_overwrite(reps, tmp_path, capsys, header, message):
    image = next(p for p in reps["root"].rglob("*.jpg") if "left_rgb" in p.parts)
    csv = tmp_path / "m.csv"
    csv.write_text(header + "\n" + ",".join([str(image), *["1"] * header.count(",")]) + "\n")
    argv = ["scores", str(csv), "--data", str(reps["root"]), "-o", str(tmp_path / "o")]
    assert main(argv) == 2
    _one_line(capsys, message)


def test_huge_bootstrap_is_one_line(reps, tmp_path, capsys):
    argv = ["merge", str(reps["tmp"] / "a"), "--bootstrap", "100000000000", "-o",
            str(tmp_path / "m")]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, "GiB", "lower --bootstrap")


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--predictions", "P", "--provider", "cpu"], "--provider does nothing"),
        (["--predictions", "P", "--precision", "fp32"], "--precision does nothing"),
        (["--onnx", "m.onnx", "--precision", "fp32"], "--precision does nothing"),  # as exported
        # A subcommand's parser has no such flag at all.
        (["merge", "A", "--provider", "cpu"], "merge: error: unrecognized arguments: --provider"),
        (["compare", "A", "A", "--hardest", "2"], "unrecognized arguments: --hardest 2"),
        (["scores", "S.csv", "--palette", "uavid"], "unrecognized arguments: --palette uavid"),
        (["scores", "S.csv", "--masks", "M"], "unrecognized arguments: --masks"),
        (["compare", "A", "A", "--workers", "2"], "unrecognized arguments: --workers 2"),
        (["merge", "A", "--workers", "2"], "unrecognized arguments: --workers 2"),
    ],
)
def test_options_that_do_nothing_are_refused(reps, tmp_path, capsys, extra, said):
    names = {"P": reps["tmp"] / "pred_a", "A": reps["tmp"] / "a", "S.csv": tmp_path / "s.csv",
             "M": tmp_path}  # fmt: skip
    argv = [str(names.get(a, a)) for a in extra]
    assert main([*argv, "--data", str(reps["root"]), "-o", str(tmp_path / "o")]
                if extra[0] not in ("merge", "compare")
                else [*argv, "-o", str(tmp_path / "o")]) == 2  # fmt: skip
    _one_line(capsys, said)


def test_compare_without_intervals_excludes_nothing(reps, tmp_path):
    """--bootstrap 0: no interval, so the "interval excludes 0" column says "–", not "no"."""
    out = tmp_path / "cmp"
    argv = ["compare", str(reps["tmp"] / "a"), str(reps["tmp"] / "b"), "--bootstrap", "0",
            "-o", str(out)]  # fmt: skip
    assert main(argv) == 0
    lines = (out / "compare.md").read_text().splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.endswith("| interval excludes 0 |"))
    # The mIoU table's rows: up to the first line that is not a row (the other measures'
    # tables follow, each with its own header).
    rows = list(itertools.takewhile(lambda ln: ln.startswith("| "), lines[start + 2 :]))
    assert rows
    for line in rows:  # bins and overall: a gap, no interval, p-value and mark "–"
        assert [c.strip() for c in line.strip("| ").split("|")][-2:] == ["–", "–"], line


def test_a_scores_report_is_not_replaced_by_an_evaluation(reps, tmp_path, capsys, saved_figures):
    """Evaluating into a scores report folder needs --overwrite, and leaves none of its plots."""
    images = sorted(p for p in reps["root"].rglob("*.jpg") if "left_rgb" in p.parts)[:5]
    err = dict(zip(images, [0.5, 4.0, 1.5, 9.0, 2.0], strict=True))
    csv = tmp_path / "m.csv"
    csv.write_text("path,err\n" + "".join(f"{p},{v}\n" for p, v in err.items()))
    out = tmp_path / "rep"
    argv = ["scores", str(csv), "--data", str(reps["root"]), "--split", "all", "--bins", "1",
            "--bootstrap", "0", "-o", str(out)]  # fmt: skip
    assert main(argv) == 0 and (out / "err_per_bin.png").is_file()
    # What the plots show: one bar at the mean error (17 / 5), the overall mean dashed at the
    # same height; each image at (its delentropy, its error).
    (axes,) = saved_figures["err_per_bin.png"].axes
    assert [bar.get_height() for bar in axes.patches] == pytest.approx([17 / 5])
    assert axes.lines[-1].get_ydata()[0] == pytest.approx(17 / 5)
    report = _json(out)
    points = saved_figures["err_vs_delent.png"].axes[0].collections[0].get_offsets()
    expected = [(row["delent"], err[Path(row["path"])]) for row in report["images"]]
    np.testing.assert_allclose(sorted(map(tuple, np.asarray(points))), sorted(expected))
    evaluation = ["--predictions", str(reps["tmp"] / "pred_a"), *reps["common"], "-o", str(out)]
    assert main(evaluation) == 2
    _one_line(capsys, "holds a scores report", "--overwrite")
    assert _json(out)["source"]["kind"] == "scores"
    assert main([*evaluation, "--overwrite"]) == 0
    assert _json(out)["source"]["kind"] == "predictions"
    assert not (out / "err_per_bin.png").exists() and not (out / "err_vs_delent.png").exists()
    assert main(argv) == 2  # and back: an mIoU report is not the --scores run's to replace
    _one_line(capsys, "holds an mIoU report")


def test_a_report_and_its_own_rebinning_are_not_comparable(reps, tmp_path):
    """--merge A --bins 5 holds A's predictions: no paired gaps between a model and itself;
    other class sets are not comparable either."""
    rebinned = tmp_path / "a5"
    assert main(["merge", str(reps["tmp"] / "a"), "--bins", "5", "-o", str(rebinned)]) == 0
    out = tmp_path / "cmp"
    assert main(["compare", str(reps["tmp"] / "a"), str(rebinned), "-o", str(out)]) == 0
    comp = json.loads((out / "compare.json").read_text())["comparisons"][0]
    assert comp["comparable"] is False and "one run seen twice" in comp["reason"]
    assert comp["overall"] is None and comp["bins"] == []
    text = (out / "compare.md").read_text()
    assert "**not comparable**" in text and "**yes**" not in text and "paired (" not in text
    # B, a different model on the same images, stays comparable.
    assert main(["compare", str(reps["tmp"] / "a"), str(reps["tmp"] / "b"), "-o",
                 str(tmp_path / "ab")]) == 0  # fmt: skip
    ab = json.loads((tmp_path / "ab" / "compare.json").read_text())["comparisons"][0]
    assert ab.get("comparable", True) and ab["paired"] is True
    import dataclasses

    from claravid.eval.analysis.gaps import not_comparable
    from claravid.eval.report.files import load_result

    a = load_result(reps["tmp"] / "a")
    other = dataclasses.replace(a, classes=[f"c{i}" for i in range(len(a.classes) + 1)])
    assert "different class sets" in not_comparable(a, other, "a", "x")


@pytest.mark.parametrize("mode", ["evaluate", "merge", "scores", "api"])
def test_a_users_plots_in_a_report_folder_are_kept(reps, tmp_path, mode):
    """Issue 24 item 7: a report replaces the files it wrote, known by name, not every file
    named like a plot (``*_per_bin.png``, ``*_vs_delent.png``): a user's own are kept, the old
    report's own are gone."""
    import claravid.eval as ev

    out = tmp_path / "rep"
    image_paths = sorted(p for p in reps["root"].rglob("*.jpg") if "left_rgb" in p.parts)[::6]
    six = tmp_path / "six.txt"  # 6 frames, one per viewpoint folder: a small report
    six.write_text("".join(f"{p.parts[-4]}/{p.parts[-2]}/{p.stem}\n" for p in image_paths))
    common = [str(six) if a == "all" else a for a in reps["common"]]
    csv = tmp_path / "m.csv"
    if mode == "scores":  # a scores report of metric "err", replaced by one of "psnr"
        csv.write_text("path,err\n" + "".join(f"{p},{i}\n" for i, p in enumerate(image_paths)))
        argv = ["scores", str(csv), "--data", str(reps["root"]), "--bins", "2", "--bootstrap",
                "0", "-o", str(out)]  # fmt: skip
        assert main(argv) == 0
        old_own = ["err_per_bin.png", "err_vs_delent.png"]
    else:  # an mIoU report with tiles, replaced by one without
        argv = ["--predictions", str(reps["tmp"] / "pred_a"), *common, "--tiles", "32", "-o",
                str(out)]  # fmt: skip
        assert main(argv) == 0
        old_own = ["tiles.png"]
    assert all((out / name).is_file() for name in old_own)
    mine = {"baseline_per_bin.png": b"my baseline", "paper_vs_delent.png": b"the paper's",
            "notes_per_bin.png.txt": b"notes"}  # fmt: skip
    for name, data in mine.items():
        (out / name).write_bytes(data)
    if mode == "evaluate":
        argv = ["--predictions", str(reps["tmp"] / "pred_b"), *common, "-o", str(out)]
        assert main(argv) == 0
    elif mode == "merge":  # re-binned in place: the report's own folder
        assert main(["merge", str(out), "--bins", "2", "--bootstrap", "0", "-o", str(out)]) == 0
    elif mode == "scores":
        csv.write_text("path,psnr\n" + "".join(f"{p},{i}\n" for i, p in enumerate(image_paths)))
        assert main(argv) == 0
        assert (out / "psnr_per_bin.png").is_file() and (out / "psnr_vs_delent.png").is_file()
    else:
        data = ev.DataChoice(root=reps["root"], split=six, palette="uavid")
        ev.evaluate(out, predictions=reps["tmp"] / "pred_b", data=data,
                    report=ev.ReportSettings(bootstrap=ev.Bootstrap(resamples=0)))  # fmt: skip
    for name, data in mine.items():
        assert (out / name).read_bytes() == data, name
    for name in old_own:
        assert not (out / name).exists(), name

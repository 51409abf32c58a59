"""``claravid-eval scores``: any per-image metric against complexity, checked by hand."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import stats

from claravid.dsp import image_complexity
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    correlation_interval,
    mean_interval,
)
from claravid.eval.cli.evaluate import main

PSNR = {"seq1": [20.0, 22.0, 27.0], "seq2": [30.0, 26.0], "seq3": [25.0, 21.0]}
SSIM = {"seq1": [0.5, 0.6, 0.9], "seq2": [0.8, 0.7], "seq3": [0.65, 0.55]}


@pytest.fixture(scope="module")
def uavid_test(tmp_path_factory):
    """uavid_test (images only, no labels) with 3 sequences of 2-3 random 40×30 frames; the
    CSV of hand-written PSNR/SSIM values (relative paths for seq1, absolute for the others)."""
    tmp = tmp_path_factory.mktemp("scores")
    root = tmp / "uavid"
    rng = np.random.default_rng(5)
    rows, paths = [], []
    for seq, values in PSNR.items():
        folder = root / "uavid_test" / seq / "Images"
        folder.mkdir(parents=True)
        for i, (psnr, ssim) in enumerate(zip(values, SSIM[seq], strict=True)):
            # Smooth to noisy images: a spread of delentropy.
            noise = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
            image = cv2.GaussianBlur(noise, (0, 0), 0.5 + 3 * (i % 3) + (seq == "seq2"))
            path = folder / f"{i:06d}.png"
            cv2.imwrite(str(path), image)
            name = path.relative_to(root).as_posix() if seq == "seq1" else str(path)
            rows.append(f"{name},{psnr},{ssim}")
            paths.append(path)
    csv = tmp / "scores.csv"
    csv.write_text("path,psnr,ssim\n" + "\n".join(rows) + "\n")
    return {"root": root, "csv": csv, "paths": paths, "tmp": tmp}


def _args(case, out, *extra, csv=None):
    return ["scores", str(csv or case["csv"]), "--data", str(case["root"]), "--dataset",
            "uavid", "--split", "test", "--output", str(out), *extra]  # fmt: skip


def test_scores_means_groups_and_correlations_by_hand(uavid_test, tmp_path):
    out = tmp_path / "rep"
    argv = _args(uavid_test, out, "--group-by", "sequence", "--bins", "2", "--bootstrap", "200")
    assert main([*argv, "--measures", "delent,pixent"]) == 0
    report = json.loads((out / "report.json").read_text())
    psnr = np.array([v for vs in PSNR.values() for v in vs])
    ssim = np.array([v for vs in SSIM.values() for v in vs])
    delent = np.array([image_complexity(p) for p in uavid_test["paths"]])
    assert report["uncertainty"]["cluster"] == "sequence"  # UAVid default
    assert report["uncertainty"]["num_clusters"] == 3
    assert report["overall"]["scores"]["psnr"]["mean"] == pytest.approx(psnr.mean())
    # Quantile bins by (delentropy, path): the 4 lowest, then the 3 highest.
    order = sorted(range(7), key=lambda i: (delent[i], str(uavid_test["paths"][i])))
    low, high = report["bins"]
    assert (low["num_images"], high["num_images"]) == (4, 3)
    assert low["scores"]["psnr"]["mean"] == pytest.approx(psnr[order[:4]].mean())
    assert high["scores"]["ssim"]["mean"] == pytest.approx(ssim[order[4:]].mean())
    assert low["lo"] == pytest.approx(delent[order[0]])
    groups = {g["name"]: g for g in report["groups"]}
    assert sorted(groups) == ["seq1", "seq2", "seq3"]
    for seq, values in PSNR.items():
        g = groups[seq]
        assert g["num_images"] == len(values)
        assert g["scores"]["psnr"]["mean"] == pytest.approx(np.mean(values))
        assert g["scores"]["ssim"]["mean"] == pytest.approx(np.mean(SSIM[seq]))
        # A note where α and β are null (seq2, seq3: 2 images each).
        assert set(g["profile"]) - {"note"} == {"mu", "sigma", "alpha", "beta"}
        # One cluster per sequence group: no interval, and the note says why.
        assert g["scores"]["psnr"]["ci"] is None and "at least 2" in g["scores"]["psnr"]["ci_note"]
    seq1 = [i for i, p in enumerate(uavid_test["paths"]) if "seq1" in str(p)]
    assert groups["seq1"]["profile"]["mu"] == pytest.approx(delent[seq1].mean(), abs=1e-6)
    corr = report["correlation"]["delent"]["psnr"]
    assert corr["n"] == 7
    assert corr["pearson"] == pytest.approx(stats.pearsonr(delent, psnr).statistic)
    assert corr["spearman"] == pytest.approx(stats.spearmanr(delent, psnr).statistic)
    assert set(report["correlation"]) == {"delent", "pixent"}
    # The intervals restated: clusters are the sequences of the report's images.
    ordered = [row["path"] for row in report["images"]]
    ids = cluster_ids([Path(p).parent.parent.name for p in ordered])
    values = np.array([row["psnr"] for row in report["images"]])
    x = np.array([row["delent"] for row in report["images"]])
    settings = Bootstrap(resamples=200, cluster="sequence")
    ci = correlation_interval(x, values, ids, settings, stream="correlation:delent:psnr")
    assert corr["pearson_ci"] == pytest.approx(ci["pearson_ci"])
    assert corr["spearman_ci"] == pytest.approx(ci["spearman_ci"])
    mean = mean_interval(values, ids, range(7), settings, stream="overall:psnr")
    assert report["overall"]["scores"]["psnr"]["ci"] == pytest.approx(mean["ci"])
    text = (out / "report.md").read_text()
    assert "| group | images | DSP μ | σ | α | β | psnr | ssim |" in text
    for name in ("psnr_per_bin.png", "ssim_per_bin.png"):  # 2 bins: 5.2 x 4 in at 100 dpi
        image = cv2.cvtColor(cv2.imread(str(out / name)), cv2.COLOR_BGR2RGB)
        assert image.shape == (400, 520, 3)
        green = (np.abs(image.astype(int) - (44, 160, 44)).sum(axis=2) < 10).sum()
        assert green > 1000  # the two bars (tab:green)
    scatter = cv2.imread(str(out / "psnr_vs_delent.png"))
    assert scatter.shape == (450, 600, 3) and (scatter < 250).any(axis=2).mean() > 0.02


def test_folder_group_by_on_a_folder_dataset(tmp_path):
    rng = np.random.default_rng(0)
    rows = []
    for sub, values in (("a", [1.0, 3.0]), ("b/c", [10.0, 20.0, 60.0])):
        (tmp_path / "img" / sub).mkdir(parents=True)
        for i, v in enumerate(values):
            cv2.imwrite(str(tmp_path / "img" / sub / f"{i}.png"),
                        rng.integers(0, 256, (20, 24, 3), dtype=np.uint8))  # fmt: skip
            rows.append(f"{sub}/{i}.png,{v}")
    (tmp_path / "s.csv").write_text("path,err\n" + "\n".join(rows) + "\n")
    out = tmp_path / "rep"
    argv = ["scores", str(tmp_path / "s.csv"), "--data", str(tmp_path / "img"), "--dataset",
            "folder", "--group-by", "folder", "--bins", "1", "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    groups = {g["name"]: g["scores"]["err"]["mean"] for g in report["groups"]}
    assert groups == {"a": pytest.approx(2.0), "b/c": pytest.approx(30.0)}
    assert report["uncertainty"]["cluster"] == "folder"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("file,psnr\nx.png,1\n", "has no 'path' column"),
        ("path\nuavid_test/seq1/Images/000000.png\n", "no metric column"),
        (
            "path,psnr\nuavid_test/seq1/Images/000000.png,abc\nuavid_test/seq1/Images/000001.png,"
            "nan\n",
            "row 2 psnr='abc', row 3 psnr='nan'",
        ),
        (
            "path,psnr\nuavid_test/seq1/Images/000000.png,1\nuavid_test/seq1/Images/000001.png,2\n"
            "uavid_test/seq1/Images/../Images/000000.png,3\n",
            "row 4 repeats row 2",
        ),
        (
            "path,psnr\nuavid_test/seq1/Images/000000.png,1\nuavid_test/seq9/Images/000000.png,2\n",
            "not in the data",
        ),
        ("path,psnr\n,1\n", "empty 'path' in row 2"),
        # Rows as a spreadsheet numbers them: blank lines count (rows 2-3 blank, row 5 bad).
        (
            "path,psnr\n\n\nuavid_test/seq1/Images/000000.png,1\n"
            "uavid_test/seq1/Images/000001.png,nan\n",
            "row 5 psnr='nan'",
        ),
        (
            "path,psnr\nuavid_test/seq1/Images/000000.png,1\n\n"
            "uavid_test/seq1/Images/../Images/000000.png,3\n",
            "row 4 repeats row 2",
        ),
        ("path,psnr\n\nuavid_test/seq9/Images/000000.png,2\n", "row 3 "),
        ("path,psnr\nuavid_test/seq1/Images/000000.png,1,2\n", "more cells than header columns"),
    ],
)
def test_bad_csv_names_the_rows(uavid_test, tmp_path, capsys, content, message):
    csv = tmp_path / "bad.csv"
    csv.write_text(content)
    assert main(_args(uavid_test, tmp_path / "x", csv=csv)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "x").exists()


def test_scores_refuse_units_the_data_lacks(uavid_test, tmp_path, capsys):
    assert main(_args(uavid_test, tmp_path / "x", "--group-by", "mission")) == 2
    assert "--group-by mission" in capsys.readouterr().err
    assert main(_args(uavid_test, tmp_path / "y", "--cluster", "block")) == 2
    assert "--cluster block is not available" in capsys.readouterr().err


def test_group_by_viewpoint_follows_the_one_rule(claravid_root, tmp_path):
    """--scores groups as every other report does: a viewpoint is mission/viewpoint, so the
    two missions of the tiny tree give 12 groups (not 6 with missions merged), and the rows
    hold the images group_indices gives them."""
    from claravid.eval.inputs.datasets import open_data

    data = open_data(claravid_root, split="all", palette="uavid", labels=False)
    expected = data.groups("viewpoint")
    csv = tmp_path / "m.csv"
    csv.write_text("path,err\n" + "".join(f"{p},{i}\n" for i, p in enumerate(data.paths)))
    out = tmp_path / "rep"
    argv = ["scores", str(csv), "--data", str(claravid_root), "--split", "all",
            "--group-by", "viewpoint", "--bootstrap", "0", "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    groups = {g["name"]: g for g in report["groups"]}
    assert len(groups) == len(expected) == 12
    assert all(name.count("/") == 1 for name in groups)  # mission/viewpoint
    for name, members in expected.items():
        # The metric is each image's position: the group's mean names its images.
        assert groups[name]["num_images"] == len(members)
        assert groups[name]["scores"]["err"]["mean"] == pytest.approx(np.mean(members))


def test_scores_report_prints_once_refuses_compare_and_says_beta_na(uavid_test, tmp_path, capsys):
    """Each order warning printed once; --compare/--merge of a scores report say what it is;
    groups of 2 images get α, β "n/a" with a note, not 0.000."""
    out = tmp_path / "rep"
    argv = _args(uavid_test, out, "--group-by", "sequence", "--bins", "3", "--bootstrap", "200")
    assert main(argv) == 0
    captured = capsys.readouterr()
    report = json.loads((out / "report.json").read_text())
    messages = report["uncertainty"]["warnings"]
    assert messages, "the fixture should give an order warning"
    for message in messages:
        assert (captured.out + captured.err).count(message) == 1, message
    seq2 = next(g for g in report["groups"] if g["name"] == "seq2")["profile"]
    assert seq2["alpha"] is None and seq2["beta"] is None and "at least 3" in seq2["note"]
    text = (out / "report.md").read_text()
    assert "| n/a | n/a |" in text and "seq2: α, β n/a (a Beta fit needs" in text
    assert "0.000 | 0.000" not in text
    for mode in (
        ["compare", str(out), str(out)],
        ["merge", str(out), "-o", str(tmp_path / "m")],
    ):
        assert main(mode) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "is a scores report" in err[0], err

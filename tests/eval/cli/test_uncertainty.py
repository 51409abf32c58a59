"""Intervals, comparisons with a verdict and ``scores`` through the command line (issue 14).

One tiny ClaraVid tree (36 frames of 64×48), hand-made label maps: A (10 % of pixels shifted
by one class), B identical to A, C with 40 % shifted (an injected error).
"""

import json
import shutil

import cv2
import numpy as np
import pytest

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.analysis.bins import quantile_bins
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    confusion_interval,
    correlation_interval,
    unpaired_gap,
)
from claravid.eval.analysis.metrics import mean_iou
from claravid.eval.cli.evaluate import main
from claravid.io import modalities
from claravid.io.layout import MISSIONS, frame_file
from tests.helpers.files import write_noisy_predictions

K = 8  # uavid palette


@pytest.fixture(scope="module")
def runs(claravid_root, tmp_path_factory):
    """Reports of A, B (= A) and C (injected error) over all 36 frames, and A over a subset."""
    tmp = tmp_path_factory.mktemp("unc")
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    for name, share, seed in (("a", 0.1, 0), ("b", 0.1, 0), ("c", 0.4, 1)):
        write_noisy_predictions(ds, tmp / f"pred_{name}", share, seed)
    common = ["--data", str(claravid_root), "--split", "all", "--palette", "uavid",
              "--no-progress", "--bootstrap", "300"]  # fmt: skip
    for name in "abc":
        argv = ["--predictions", str(tmp / f"pred_{name}"), *common, "--output", str(tmp / name)]
        assert main([*argv, "--group-by", "mission"]) == 0
    subset = tmp / "subset.txt"
    subset.write_text("\n".join(f.key for f in ds.frames[::2]) + "\n")
    half = [a if a != "all" else str(subset) for a in common]
    assert main(["--predictions", str(tmp / "pred_a"), *half, "--output", str(tmp / "half")]) == 0
    return {"tmp": tmp, "ds": ds, "common": common}


def _report(folder):
    return json.loads((folder / "report.json").read_text())


def _blocks_by_hand(root, frames, size=150.0):
    """(mission, column, row) per frame on the grid of docs/data.md: per mission, the fewest
    blocks whose span exceeds the extent of its camera positions, centred on it."""
    xy = np.array([
        modalities.read_extrinsics(frame_file(root / MISSIONS[f.mission], f.viewpoint, f.stem,
                                              "extrinsics"))[:2, 3]
        for f in frames
    ])  # fmt: skip
    missions = np.array([f.mission for f in frames])
    origin = np.empty_like(xy)
    for mission in set(missions.tolist()):
        lo, hi = xy[missions == mission].min(axis=0), xy[missions == mission].max(axis=0)
        origin[missions == mission] = (lo + hi) / 2 - (np.floor((hi - lo) / size) + 1) * size / 2
    cells = np.floor((xy - origin) / size).astype(int).tolist()
    return [(f.mission, x, y) for f, (x, y) in zip(frames, cells, strict=True)]


def test_intervals_everywhere_with_block_clusters(runs, claravid_root):
    report = _report(runs["tmp"] / "a")
    unc = report["uncertainty"]
    blocks = _blocks_by_hand(claravid_root, runs["ds"].frames)
    assert unc["method"] == "cluster percentile bootstrap" and unc["cluster"] == "block"
    assert (unc["resamples"], unc["level"], unc["seed"]) == (300, 0.95, 0)
    assert unc["num_clusters"] == len(set(blocks)) >= 2
    # Every interval resamples the hand-computed blocks of the saved confusions: restated
    # per set (overall, each quantile bin, each mission) from the report's own images.
    with np.load(runs["tmp"] / "a" / "confusions.npz") as saved:
        conf = saved["confusions"]
        assert sorted(set(saved["attribute_block"])) == sorted(
            {f"{MISSIONS[m]}/{x}_{y}" for m, x, y in blocks}
        )
    ids = cluster_ids([str(b) for b in blocks])
    settings = Bootstrap(resamples=300)
    paths = [row["path"] for row in report["images"]]
    delent = np.array([row["delent"] for row in report["images"]])
    missions = [f.mission for f in runs["ds"].frames]
    sets = [("overall", report["overall"], range(len(conf)))]
    sets += [
        (f"bin:{b.name}", row, b.indices)
        for b, row in zip(quantile_bins(delent, paths, 3), report["bins"], strict=True)
    ]
    for row in report["groups"]:
        members = [i for i, m in enumerate(missions) if m == row["name"]]
        sets.append((f"group:{row['name']}", row, members))
    for stream, row, members in sets:
        expected = confusion_interval(conf, ids, members, settings, stream=stream)
        assert row["miou_ci"] == pytest.approx(expected["miou_ci"]), stream
        assert row["pixel_acc_ci"] == pytest.approx(expected["pixel_acc_ci"]), stream
        assert row["ci_note"] is None
    corr = report["correlation"]["delent"]
    per_image = np.array([mean_iou(c) for c in conf])
    expected = correlation_interval(delent, per_image, ids, settings, stream="correlation:delent")
    assert corr["pearson_ci"] == pytest.approx(expected["pearson_ci"])
    assert corr["spearman_ci"] == pytest.approx(expected["spearman_ci"])
    text = (runs["tmp"] / "a" / "report.md").read_text()
    o = report["overall"]
    assert f"{o['miou']:.3f} [{o['miou_ci'][0]:.3f}, {o['miou_ci'][1]:.3f}]" in text


def test_merge_rebins_and_bootstraps_without_the_data(runs, tmp_path):
    copy = shutil.copytree(runs["tmp"] / "a", tmp_path / "a")  # no data, no predictions needed
    out = tmp_path / "m"
    argv = ["merge", str(copy), "--bins", "2", "--cluster", "viewpoint", "--seed", "3",
            "--bootstrap", "200", "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    report = _report(out)
    assert report["uncertainty"]["cluster"] == "viewpoint"
    assert report["uncertainty"]["num_clusters"] == 12  # 2 missions × 6 viewpoints
    assert len(report["bins"]) == 2 and all(b["miou_ci"] for b in report["bins"])
    again = tmp_path / "m2"
    assert main([*argv[:-1], str(again)]) == 0
    assert _report(again)["bins"] == report["bins"]  # same seed, same numbers
    off = tmp_path / "off"
    assert main(["merge", str(copy), "--bootstrap", "0", "--output", str(off)]) == 0
    overall = _report(off)["overall"]
    assert overall["miou_ci"] is None and "off" in overall["ci_note"]


def test_compare_identical_and_injected_error(runs, tmp_path, capsys):
    tmp = runs["tmp"]
    out = tmp_path / "cmp"
    argv = ["compare", str(tmp / "a"), str(tmp / "b"), str(tmp / "c"), "--bootstrap", "300",
            "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    result = json.loads((out / "compare.json").read_text())
    assert result["baseline"] == "a" and result["uncertainty"]["cluster"] == "block"
    same, worse = result["comparisons"]
    # B is another run whose label maps equal A's: comparable, a paired gap of exactly 0 (a
    # report and its own re-binning is what is not comparable: test_compare_lineage.py).
    assert same["report"] == "b" and same["comparable"] is True and same["paired"] is True
    for row in (same["overall"], *same["bins"]):
        assert (row["gap"], row["gap_ci"], row["p_value"]) == (0.0, [0.0, 0.0], 1.0)
    a, c = _report(tmp / "a"), _report(tmp / "c")
    assert worse["paired"] and worse["overall"]["gap"] == pytest.approx(
        c["overall"]["miou"] - a["overall"]["miou"]
    )
    assert worse["overall"]["gap_ci"][1] < 0 and worse["overall"]["p_value"] < 0.01
    text = (out / "compare.md").read_text()
    assert "**yes**" in text and "paired" in text
    _check_compare_png(out / "compare.png", bins=3, reports=3)


def _check_compare_png(path, bins, reports):
    """compare.png read back: the figure's size (two panels at 100 dpi), bars of every report
    in the top panel (matplotlib's C0, C1, ...) and gap bars (C1, C2, ...) in the bottom one."""
    image = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    assert image.shape == (900, int(100 * max(6, 1.8 * bins + 2)), 3)
    colours = [(31, 119, 180), (255, 127, 14), (44, 160, 44)]  # C0, C1, C2
    top, bottom = image[:450], image[450:]

    def drawn(panel, rgb):
        return int((np.abs(panel.astype(int) - rgb).sum(axis=2) < 10).sum())

    for k in range(reports):
        assert drawn(top, colours[k]) > 100, f"no bars of report {k}"
    # B = A draws a gap bar of height 0; the injected error's gap is drawn.
    assert drawn(bottom, colours[reports - 1]) > 100


def test_compare_different_images_is_unpaired(runs, tmp_path):
    tmp = runs["tmp"]
    out = tmp_path / "cmp"
    assert main(["compare", str(tmp / "a"), str(tmp / "half"), "--bootstrap", "100",
                 "--output", str(out)]) == 0  # fmt: skip
    comp = json.loads((out / "compare.json").read_text())["comparisons"][0]
    assert comp["paired"] is False and "unpaired" in comp["note"]
    assert comp["overall"]["paired"] is False
    # The unpaired gap restated: A over all its images, the half over its own, resampled
    # independently with A's block clusters and the half's.
    with np.load(tmp / "a" / "confusions.npz") as a, np.load(tmp / "half" / "confusions.npz") as h:
        conf_a, conf_h = a["confusions"], h["confusions"]
        ids_a, ids_h = cluster_ids(a["attribute_block"]), cluster_ids(h["attribute_block"])
    settings = Bootstrap(resamples=100, cluster="block")
    expected = unpaired_gap(conf_a, ids_a, range(len(conf_a)), conf_h, ids_h,
                            range(len(conf_h)), settings, stream="compare:1:overall")  # fmt: skip
    assert comp["overall"]["gap"] == pytest.approx(expected["gap"])
    assert comp["overall"]["gap_ci"] == pytest.approx(expected["gap_ci"])
    assert "unpaired" in (out / "compare.md").read_text()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--bootstrap", "-1"], "--bootstrap (resamples) must be >= 0"),
        (["--ci-level", "1.5"], "--ci-level (the interval level) must be between 0 and 1"),
        (["--cluster", "tile"], "unknown --cluster 'tile'"),
        (["--cluster", "sequence"], "--cluster sequence is not available"),
    ],
)
def test_bad_uncertainty_arguments(runs, tmp_path, capsys, extra, message):
    argv = ["--predictions", str(runs["tmp"] / "pred_a"), *runs["common"], *extra,
            "--output", str(tmp_path / "x")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "x").exists()


def test_block_without_extrinsics_is_refused(writable_root, tmp_path, capsys):
    for f in writable_root.glob("*/extrinsics/*/*"):
        f.unlink()
    ds = ClaraVidSegmentation(writable_root, split="all", palette="uavid")
    write_noisy_predictions(ds, tmp_path / "p", 0.1, 0)
    argv = ["--predictions", str(tmp_path / "p"), "--data", str(writable_root), "--split", "all",
            "--palette", "uavid", "--no-progress", "--output", str(tmp_path / "x")]  # fmt: skip
    assert main([*argv, "--cluster", "block"]) == 2
    err = capsys.readouterr().err
    assert "--cluster block is not available" in err and "extrinsics" in err
    # Without --cluster the default falls back to the viewpoint.
    assert main([*argv, "--bootstrap", "100"]) == 0
    assert _report(tmp_path / "x")["uncertainty"]["cluster"] == "viewpoint"


def test_paired_compare_aligns_images_by_path():
    """B lists the same images as A in another order: the pairs follow the paths, so the gaps
    equal those of B listed in A's order, and differ from pairing rows by position."""
    from claravid.eval.analysis.gaps import gap_analysis
    from claravid.eval.analysis.table import EvalResult

    rng = np.random.default_rng(0)
    conf = rng.integers(0, 50, size=(12, 3, 3)) + np.eye(3, dtype=np.int64) * 400
    better = conf + np.eye(3, dtype=np.int64) * rng.integers(0, 200, size=(12, 1, 1))
    paths = [f"img{i:02d}.png" for i in range(12)]
    attrs = {"folder": [f"f{i // 3}" for i in range(12)]}

    def result(rows, confusions):
        return EvalResult([paths[i] for i in rows], [paths[i] for i in rows], confusions, {},
                          {"folder": [attrs["folder"][i] for i in rows]}, ["x", "y", "z"], "p",
                          {"dataset": "folder"})  # fmt: skip

    a, in_order = result(range(12), conf), result(range(12), better)
    order = rng.permutation(12)
    shuffled = result(order, better[order])
    by_position = result(range(12), better[order])  # B's rows put on A's paths by position
    report, settings = {"source": {"binning": {}}}, Bootstrap(resamples=100, cluster="folder")

    def overall(b):
        out = gap_analysis([a, b], [report, report], ["a", "b"], settings)["comparisons"][0]
        assert out["paired"]
        return out["overall"]

    assert overall(shuffled) == overall(in_order)
    assert overall(by_position)["gap_ci"] != overall(in_order)["gap_ci"]

"""Tile-level complexity (``--tiles``): confusions per tile, bins over tiles, merge, the plot.

Expected values are counted by hand or with the official recipe on the cropped pixels.
"""

import json
import re

import cv2
import numpy as np
import pytest
from scipy import stats

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.metrics import mean_iou
from claravid.eval.analysis.tile_bins import TileTable, concat_tables, tile_report
from claravid.eval.cli.evaluate import main
from claravid.eval.measures.confusion import tile_confusions
from claravid.eval.report.markdown import bin_table
from tests.claravid.dsp.reference import official_delentropy

K = 8  # uavid palette


def _count(pred, truth, k):
    """The confusion by a plain loop over pixels (rows = truth, 255 ignored)."""
    out = np.zeros((k, k), dtype=np.int64)
    for t, p in zip(truth.ravel(), pred.ravel(), strict=True):
        if t != 255:
            out[t, p] += 1
    return out


def test_tile_confusions_by_hand():
    rng = np.random.default_rng(0)
    truth = rng.integers(0, 3, (5, 7)).astype(np.uint8)
    truth[0, 0] = 255
    pred = rng.integers(0, 3, (5, 7)).astype(np.uint8)
    tiles = tile_confusions(pred, truth, 3, 3)
    # 5/3 = 1.67 -> 2 rows, bounds 0, round(2.5) = 2, 5; 7/3 = 2.33 -> 2 cols: 0, round(3.5) = 4, 7
    assert tiles.shape == (2, 2, 3, 3)
    for r, (y0, y1) in enumerate([(0, 2), (2, 5)]):
        for c, (x0, x1) in enumerate([(0, 4), (4, 7)]):
            assert (
                tiles[r, c].tolist() == _count(pred[y0:y1, x0:x1], truth[y0:y1, x0:x1], 3).tolist()
            )
    assert tiles.sum(axis=(0, 1)).tolist() == _count(pred, truth, 3).tolist()


def _table():
    """Two images, 2 tiles each; K = 2. Image 1's second tile has no valid pixel."""
    conf = np.array([
        [[5, 1], [0, 4]],  # img0 (0,0)
        [[2, 2], [2, 2]],  # img0 (0,1)
        [[9, 0], [1, 0]],  # img1 (0,0)
        [[0, 0], [0, 0]],  # img1 (0,1): all ignored
    ])  # fmt: skip
    return TileTable(
        size=10,
        image=np.array([0, 0, 1, 1]),
        row=np.array([0, 0, 0, 0]),
        col=np.array([0, 1, 0, 1]),
        delent=np.array([3.0, 5.0, 3.0, 4.0]),
        confusions=conf,
    )


def test_tile_bins_and_correlation_by_hand():
    table = _table()
    # Sorted by (delentropy, path, row, col): b.png sorts before z.png, so image 1's 3.0 tile
    # comes first: [2, 0, 3, 1] -> low = tiles 2, 0; high = tiles 3, 1.
    report = tile_report(table, ["z.png", "b.png"], ["x", "y"], bins=2)
    low, high = report["bins"]
    assert (low["name"], low["num_tiles"], low["lo"], low["hi"]) == ("low", 2, 3.0, 3.0)
    assert (high["num_tiles"], high["lo"], high["hi"]) == (2, 4.0, 5.0)
    # low: [[14, 1], [1, 4]] -> IoU x = 14/16, y = 4/6
    assert low["miou"] == pytest.approx((14 / 16 + 4 / 6) / 2)
    assert low["pixel_acc"] == pytest.approx(18 / 20)
    # high: [[2, 2], [2, 2]] -> IoU 2/6 each
    assert high["miou"] == pytest.approx(2 / 6)
    assert report["num_tiles"] == 4 and report["num_without_labels"] == 1
    # The correlation leaves the tile without a valid pixel out: 3 pairs.
    miou = [(5 / 6 + 4 / 5) / 2, 2 / 6, 9 / 10]  # tile 2: class y has union 1, TP 0 -> IoU 0
    miou[2] = (9 / 10 + 0.0) / 2
    corr = report["correlation"]["delent"]
    assert corr["n"] == 3
    assert corr["pearson"] == pytest.approx(stats.pearsonr([3.0, 5.0, 3.0], miou).statistic)
    # Fixed edges: [3, 4) holds tiles 0, 2; [4, 5] holds 1, 3.
    fixed = tile_report(table, ["z.png", "b.png"], ["x", "y"], edges=[3.0, 4.0, 5.0])
    assert [b["num_tiles"] for b in fixed["bins"]] == [2, 2]
    assert fixed["bins"][0]["miou"] == pytest.approx(low["miou"])


def test_tile_intervals_resample_tiles_with_their_image():
    table = _table()
    settings = Bootstrap(resamples=200, seed=0)
    one = tile_report(table, ["a", "b"], ["x", "y"], bins=1, bootstrap=settings)
    # Two clusters (the images): every resample is img0 + img1, or one of them twice; resampling
    # tiles on their own would also draw e.g. tile 1 four times (mIoU 1/3), below all three.
    lo, hi = one["bins"][0]["miou_ci"]
    outcomes = [mean_iou(table.confusions[:2].sum(0)), mean_iou(table.confusions[2:].sum(0)),
                mean_iou(table.confusions.sum(0))]  # fmt: skip
    assert min(outcomes) <= lo < hi <= max(outcomes)
    # As one cluster (the same label for both images), there is nothing to resample.
    single = tile_report(table, ["a", "b"], ["x", "y"], bins=1, clusters=["m", "m"],
                         bootstrap=settings)  # fmt: skip
    assert single["bins"][0]["miou_ci"] is None and single["bins"][0]["ci_note"]


def test_concat_follows_the_merge_order():
    a, b = _table(), _table()
    b.delent = b.delent + 10
    # Merge of 2 + 2 images whose sorted order is [2, 0, 3, 1] (old index per new place).
    joined = concat_tables([a, b], [2, 2], np.array([2, 0, 3, 1]))
    assert joined.image.tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
    assert joined.delent.tolist() == [13.0, 15.0, 3.0, 5.0, 13.0, 14.0, 3.0, 4.0]
    assert concat_tables([a, None], [2, 2], np.arange(4)) is None


# -- through the command line ------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiled(claravid_root, tmp_path_factory):
    """Label maps with 10 % of pixels shifted, and a --tiles 32 report of them (64×48 frames:
    rows 48/32 = 1.5 -> 2 (0, 24, 48), columns 64/32 = 2 (0, 32, 64))."""
    tmp = tmp_path_factory.mktemp("tiles")
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    rng = np.random.default_rng(0)
    preds = tmp / "preds"
    for i, frame in enumerate(ds.frames):
        truth = ds.read_mask(i)
        valid = np.where(truth == 255, 0, truth).astype(np.uint8)
        pred = np.where(rng.random(valid.shape) < 0.1, (valid + 1) % K, valid).astype(np.uint8)
        (preds / frame.key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(preds / f"{frame.key}.png"), pred)
    common = ["--data", str(claravid_root), "--split", "all", "--palette", "uavid",
              "--no-progress", "--bootstrap", "100"]  # fmt: skip
    out = tmp / "rep"
    assert main(["--predictions", str(preds), *common, "--tiles", "32", "--output", str(out)]) == 0
    return {"tmp": tmp, "ds": ds, "preds": preds, "common": common, "out": out}


def _load(folder):
    report = json.loads((folder / "report.json").read_text())
    with np.load(folder / "confusions.npz") as npz:
        saved = {k: npz[k] for k in npz.files}
    return report, saved


def test_cli_tiles_values(tiled):
    report, saved = _load(tiled["out"])
    ds, n = tiled["ds"], len(tiled["ds"])
    tiles = report["tiles"]
    assert tiles["size"] == 32 and tiles["num_tiles"] == 4 * n
    assert report["source"]["tiles"] == 32
    # Each image's tile confusions sum to its confusion; a tile's delentropy is the official
    # recipe on the tile's pixels; its confusion is counted over the tile's pixels.
    image, row, col = saved["tile_image"], saved["tile_row"], saved["tile_col"]
    for i in (0, n - 1):
        mine = image == i
        assert mine.sum() == 4
        np.testing.assert_array_equal(saved["tile_confusions"][mine].sum(0), saved["confusions"][i])
        path = saved["paths"][i]
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        index = [str(f.paths["rgb"]) for f in ds.frames].index(str(path))
        truth = ds.read_mask(index)
        pred = cv2.imread(str(tiled["preds"] / f"{saved['keys'][i]}.png"), cv2.IMREAD_UNCHANGED)
        for t in np.flatnonzero(mine):
            y0, y1 = (0, 24) if row[t] == 0 else (24, 48)
            x0, x1 = (0, 32) if col[t] == 0 else (32, 64)
            crop = cv2.GaussianBlur(np.ascontiguousarray(gray[y0:y1, x0:x1]), (3, 3), 1.0)
            assert saved["tile_delent"][t] == pytest.approx(official_delentropy(crop), abs=1e-9)
            expected = _count(pred[y0:y1, x0:x1], truth[y0:y1, x0:x1], K)
            assert saved["tile_confusions"][t].tolist() == expected.tolist()
    # Quantile bins over tiles sorted by (delentropy, path, row, column), as array_split.
    order = sorted(range(len(image)), key=lambda t: (saved["tile_delent"][t],
                   str(saved["paths"][image[t]]), row[t], col[t]))  # fmt: skip
    for b, members in zip(tiles["bins"], np.array_split(np.array(order), 3), strict=True):
        assert b["num_tiles"] == len(members)
        conf = saved["tile_confusions"][members].sum(0)
        assert b["miou"] == pytest.approx(mean_iou(conf))
        assert b["miou_ci"][0] <= b["miou_ci"][1]
    own = [mean_iou(c) for c in saved["tile_confusions"]]
    keep = np.isfinite(own)
    corr = tiles["correlation"]["delent"]
    assert corr["n"] == int(keep.sum())
    expected = stats.spearmanr(saved["tile_delent"][keep], np.array(own)[keep]).statistic
    assert corr["spearman"] == pytest.approx(expected)
    assert "## Tiles of about 32 px" in (tiled["out"] / "report.md").read_text()
    printed = bin_table(report)
    assert "tile bin" in printed and f"n = {corr['n']}" in printed


def test_tiles_png_shows_the_hardest_images_their_tiles_and_their_errors(
    tiled, tmp_path, saved_figures
):
    """tiles.png read back as drawn: one row per hardest image (the 4 lowest per-image mIoUs,
    counted here), its pixels, its 2 x 2 tile delentropies and its wrong pixels in red."""
    out = tmp_path / "rep"
    argv = ["--predictions", str(tiled["preds"]), *tiled["common"][:-2], "--bootstrap", "0",
            "--tiles", "32", "--output", str(out)]  # fmt: skip
    assert main(argv) == 0
    _, saved = _load(out)
    ds = tiled["ds"]

    def miou(conf):  # IoU = TP / (TP + FP + FN) over classes present in truth or prediction
        tp = np.diag(conf).astype(float)
        union = conf.sum(0) + conf.sum(1) - tp
        return (tp[union > 0] / union[union > 0]).mean()

    mious = [miou(c) for c in saved["confusions"]]
    hardest = sorted(range(len(mious)), key=lambda i: (mious[i], i))[:4]
    axes = saved_figures["tiles.png"].axes[:12]  # 4 rows x 3 panels, then the colour bar
    shades = np.array([[215, 215, 215], [214, 39, 40], [255, 255, 255]])
    for row, i in enumerate(hardest):
        image_ax, tile_ax, error_ax = axes[3 * row : 3 * row + 3]
        key = str(saved["keys"][i])
        assert image_ax.get_title().splitlines()[0] == key
        rgb = cv2.cvtColor(cv2.imread(str(saved["paths"][i])), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(image_ax.images[0].get_array(), rgb)
        mine = saved["tile_image"] == i
        grid = np.zeros((2, 2))
        grid[saved["tile_row"][mine], saved["tile_col"][mine]] = saved["tile_delent"][mine]
        np.testing.assert_array_equal(tile_ax.images[0].get_array(), grid)
        truth = ds.read_mask([f.key for f in ds.frames].index(key))
        pred = cv2.imread(str(tiled["preds"] / f"{key}.png"), cv2.IMREAD_UNCHANGED)
        errors = np.where(truth == 255, 2, (pred != truth).astype(int))
        np.testing.assert_array_equal(error_ax.images[0].get_array(), shades[errors])


def test_merge_rebins_tiles_without_data(tiled):
    tmp, out = tiled["tmp"], tiled["out"]
    assert main(["merge", str(out), "--edges", "0,5,9", "--bootstrap", "0",
                 "--output", str(tmp / "fixed")]) == 0  # fmt: skip
    report, saved = _load(tmp / "fixed")
    tiles = report["tiles"]
    delent = saved["tile_delent"]
    assert [b["num_tiles"] for b in tiles["bins"]] == [
        int(((delent >= 0) & (delent < 5)).sum()),
        int(((delent >= 5) & (delent <= 9)).sum()),
    ]
    # Two halves merged give the tiles of the whole.
    ds = tiled["ds"]
    halves = []
    for part in (0, 1):
        listing = tmp / f"half{part}.txt"
        listing.write_text("\n".join(f.key for f in ds.frames[part::2]) + "\n")
        argv = [a if a != "all" else str(listing) for a in tiled["common"]]
        folder = tmp / f"half{part}"
        assert main(["--predictions", str(tiled["preds"]), *argv, "--tiles", "32",
                     "--output", str(folder)]) == 0  # fmt: skip
        halves.append(str(folder))
    assert main(["merge", *halves, "--bootstrap", "100", "--output", str(tmp / "joined")]) == 0
    joined, joined_saved = _load(tmp / "joined")
    whole, whole_saved = _load(out)
    for key in ("tile_image", "tile_row", "tile_col", "tile_delent", "tile_confusions"):
        np.testing.assert_array_equal(joined_saved[key], whole_saved[key])
    assert [b["miou"] for b in joined["tiles"]["bins"]] == [
        b["miou"] for b in whole["tiles"]["bins"]
    ]


def test_model_tiles_equal_saved_prediction_tiles(claravid_root, model_files, tmp_path):
    common = ["--data", str(claravid_root), "--split", "all", "--no-progress", "--bootstrap", "0",
              "--tiles", "32"]  # fmt: skip
    argv = ["--checkpoint", str(model_files["checkpoint"]), *common,
            "--save-predictions", str(tmp_path / "p"), "--output", str(tmp_path / "m")]  # fmt: skip
    assert main(argv) == 0
    assert main(["--predictions", str(tmp_path / "p"), *common, "--palette", "uavid",
                 "--output", str(tmp_path / "s")]) == 0  # fmt: skip
    _, model = _load(tmp_path / "m")
    _, saved = _load(tmp_path / "s")
    for key in ("tile_image", "tile_delent", "tile_confusions", "confusions"):
        np.testing.assert_array_equal(model[key], saved[key])
    assert len(model["tile_image"]) == 4 * len(model["paths"])


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--tiles", "1"], "--tiles must be at least 32 pixels"),
        (["--tiles", "2"], "--tiles must be at least 32 pixels"),  # gave -0.0 and 1.1 GB
        (["--tiles", "0"], "positive integer"),
        (["--tiles", "x"], "positive integer"),
    ],
)
def test_bad_tiles(tiled, extra, message, capsys):
    argv = ["--predictions", str(tiled["preds"]), *tiled["common"], *extra,
            "--output", str(tiled["tmp"] / "bad")]  # fmt: skip
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own type check exits
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_tiles_do_nothing_with_merge(tiled, capsys):
    assert main(["merge", str(tiled["out"]), "--tiles", "32",
                 "--output", str(tiled["tmp"] / "m2")]) == 2  # fmt: skip
    assert "unrecognized arguments: --tiles 32" in capsys.readouterr().err


def test_a_tile_grid_mismatch_names_the_image():
    """Image tiles (delentropy) and label tiles (confusions) must be one grid; the datasets
    refuse labels of another size first, this guard says which image broke it otherwise."""
    from types import SimpleNamespace

    from claravid.eval.inference.collect import _check_tile_grids

    data = SimpleNamespace(paths=["a.png", "b.png"])
    ok = (np.zeros((2, 3)), np.zeros((2, 3, K, K), np.int64))
    bad = (np.zeros((3, 2)), np.zeros((2, 3, K, K), np.int64))
    _check_tile_grids(data, [0], [ok[0]], [ok[1]])
    with pytest.raises(ValueError, match=r"b.png: the image gives a \(3, 2\) tile grid"):
        _check_tile_grids(data, [1], [bad[0]], [bad[1]])


def test_tiles_the_size_of_the_image_are_the_images(tiled):
    # Before: the tile bins drew other bootstrap streams than the image bins, so one tile per
    # image gave other intervals than the images themselves.
    out = tiled["tmp"] / "whole"
    assert main(["--predictions", str(tiled["preds"]), *tiled["common"], "--tiles", "64",
                 "--output", str(out)]) == 0  # fmt: skip
    report, saved = _load(out)
    tiles = report["tiles"]
    assert tiles["num_tiles"] == len(saved["paths"])
    np.testing.assert_array_equal(saved["tile_delent"], saved["complexity_delent"])
    for image_bin, tile_bin in zip(report["bins"], tiles["bins"], strict=True):
        for key in ("lo", "hi", "miou", "miou_ci", "pixel_acc", "pixel_acc_ci", "per_class_iou"):
            assert tile_bin[key] == image_bin[key], key
    for key, value in report["correlation"]["delent"].items():
        assert tiles["correlation"]["delent"][key] == value, key


def test_tiles_outside_fixed_edges_are_warned(tiled, capsys):
    # Before: images outside --edges were warned, tiles outside them were only counted.
    out = tiled["tmp"] / "outside"
    assert main(["merge", str(tiled["out"]), "--edges", "20,30", "--bootstrap", "0",
                 "--output", str(out)]) == 0  # fmt: skip
    report, _ = _load(out)
    n = report["tiles"]["num_tiles"]
    assert report["tiles"]["binning"]["outside"] == n
    err = capsys.readouterr().err
    assert re.search(rf"warning: {n} of {n} tile\(s\) fall outside --edges \(delentropy of the "
                     r"tiles: \d+\.\d\d\.\.\d+\.\d\d\): no tile is in a bin", err), err  # fmt: skip


def test_too_many_tiles_per_image_is_refused_before_the_work(tmp_path, capsys):
    # Before: any grid was cut (--tiles 2 took 1.1 GB for four small images).
    images, masks, preds = tmp_path / "images", tmp_path / "masks", tmp_path / "preds"
    truth = np.zeros((1200, 1200), np.uint8)
    for folder in (images, masks, preds):
        folder.mkdir()
    cv2.imwrite(str(images / "x.jpg"), np.full((1200, 1200, 3), 128, np.uint8))
    cv2.imwrite(str(masks / "x.png"), truth)
    cv2.imwrite(str(preds / "x.png"), truth)
    argv = ["--predictions", str(preds), "--dataset", "folder", "--data", str(images),
            "--masks", str(masks), "--palette", "udd6", "--bins", "1", "--no-progress",
            "--tiles", "32", "--output", str(tmp_path / "rep")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "x.jpg of 1200x1200 into 1444 tiles, more than 1024: use tiles of 37 px or more" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


@pytest.mark.parametrize(
    ("height", "width", "tiles", "message"),
    [
        # 16 rows x 64 columns of 32 px: exactly the bound, accepted.
        (512, 2048, 1024, None),
        # 25 x 41 = 1025: one past it. At 33 px, round(800/33) x round(1312/33) = 24 x 40 fit.
        (800, 1312, 1025, "x.jpg of 1312x800 into 1025 tiles, more than 1024: use tiles of 33 px"),
    ],
)
def test_the_tile_bound_is_1024_per_image(tmp_path, capsys, height, width, tiles, message):
    from claravid.dsp.tiles import check_tile_count, tile_complexities

    images, masks, preds = tmp_path / "images", tmp_path / "masks", tmp_path / "preds"
    truth = np.zeros((height, width), np.uint8)
    for folder in (images, masks, preds):
        folder.mkdir()
    gray = np.random.default_rng(0).integers(0, 256, (height, width), dtype=np.uint8)
    cv2.imwrite(str(images / "x.jpg"), np.dstack([gray] * 3))
    cv2.imwrite(str(masks / "x.png"), truth)
    cv2.imwrite(str(preds / "x.png"), truth)
    argv = ["--predictions", str(preds), "--dataset", "folder", "--data", str(images),
            "--masks", str(masks), "--palette", "udd6", "--bins", "1", "--no-progress",
            "--bootstrap", "0", "--hardest", "0", "--tiles", "32", "--output",
            str(tmp_path / "rep")]  # fmt: skip
    code = main(argv)
    err = capsys.readouterr().err
    if message is None:
        assert code == 0, err
        report, saved = _load(tmp_path / "rep")
        assert report["tiles"]["num_tiles"] == tiles
        assert (saved["tile_row"].max(), saved["tile_col"].max()) == (15, 63)
        assert check_tile_count((height, width), 32) == tiles
        assert tile_complexities(gray, 32).shape == (16, 64)
    else:
        assert code == 2 and message in err, err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        for call in (lambda: check_tile_count((height, width), 32, "x.jpg"),
                     lambda: tile_complexities(gray, 32)):  # fmt: skip
            with pytest.raises(ValueError, match="1025 tiles, more than 1024"):
                call()

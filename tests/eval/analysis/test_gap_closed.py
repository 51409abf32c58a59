"""The fraction of the source-to-oracle gap an adapted model closes, from hand-made confusions
whose IoUs are worked out below; the interval from fixed draws, the same for all three models."""

import json

import numpy as np
import pytest

from claravid.eval.analysis.bins import Bin
from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.gap_closed import gap_closed
from claravid.eval.analysis.table import EvalResult
from claravid.infra.cli import UsageError

CLASSES = ["x", "y"]
# Rows truth, columns prediction. Image 1: source IoU 3/5, 3/5; adapted 4/5, 3/4; oracle 1, 1.
# Image 2: source IoU 2/4, 4/6; adapted 1, 1; oracle 1, 1.
SOURCE = [[[3, 1], [1, 3]], [[2, 0], [2, 4]]]
ADAPTED = [[[4, 0], [1, 3]], [[2, 0], [0, 6]]]
ORACLE = [[[4, 0], [0, 4]], [[2, 0], [0, 6]]]


def _fraction(a, s, o):
    return (a - s) / (o - s)


# Image 1 alone: mIoU 0.6, 0.775, 1.
ONE = _fraction((4 / 5 + 3 / 4) / 2, 0.6, 1.0)  # 0.4375
# Image 2 alone: the adapted model is the oracle: 1.
TWO = 1.0
# Both: source [[5,1],[3,7]]: IoU 5/9, 7/11; adapted [[6,0],[1,9]]: 6/7, 9/10; oracle 1, 1.
S, A = (5 / 9 + 7 / 11) / 2, (6 / 7 + 9 / 10) / 2
BOTH = _fraction(A, S, 1.0)
BOTH_X = _fraction(6 / 7, 5 / 9, 1.0)
BOTH_Y = _fraction(9 / 10, 7 / 11, 1.0)


def _table(confusions, order=(0, 1)):
    paths = ["a.png", "b.png"]
    return EvalResult(
        paths=[paths[i] for i in order],
        keys=[f"k{i}" for i in order],
        confusions=np.asarray(confusions, dtype=np.int64)[list(order)],
        complexity={"delent": np.array([1.0, 2.0])[list(order)]},
        attributes={},
        classes=CLASSES,
        palette="p",
    )


def test_fraction_closed_per_bin_and_class_with_paired_draws():
    # The adapted report lists its images in the other order: rows are matched by image.
    source, adapted, oracle = _table(SOURCE), _table(ADAPTED, (1, 0)), _table(ORACLE)
    # Draws over the two clusters: image 1 twice, image 2 twice, each once.
    counts = np.array([[2, 0], [0, 2], [1, 1]])
    bins = [Bin("low", 1.0, 1.0, (0,)), Bin("high", 2.0, 2.0, (1,))]
    out = gap_closed(
        source,
        [adapted],
        oracle,
        ["src", "adapt", "oracle"],
        bins,
        Bootstrap(resamples=0, cluster="image"),
        counts=counts,
    )
    (entry,) = out["adapted"]
    assert entry["overall"]["closed"] == pytest.approx(BOTH)
    assert entry["overall"]["oracle_gap"] == pytest.approx(1.0 - S)
    # The same clusters for all three models: the resampled fractions are ONE, TWO, BOTH.
    expected = np.quantile([ONE, TWO, BOTH], [0.025, 0.975])
    assert entry["overall"]["closed_ci"] == pytest.approx(expected.tolist())
    assert entry["classes"]["x"]["closed"] == pytest.approx(BOTH_X)
    assert entry["classes"]["y"]["closed"] == pytest.approx(BOTH_Y)
    low, high = entry["bins"]
    assert low["name"] == "low" and low["closed"] == pytest.approx(ONE)
    assert high["closed"] == pytest.approx(TWO)
    assert out["source"] == "src" and out["oracle"] == "oracle"


def test_oracle_no_better_gives_no_fraction_and_a_note():
    source = _table(SOURCE)
    out = gap_closed(
        source,
        [_table(ADAPTED)],
        _table(SOURCE),
        ["s", "a", "o"],
        [],
        Bootstrap(resamples=0, cluster="image"),
    )
    assert out["adapted"][0]["overall"]["closed"] is None
    assert any("not better" in note for note in out["notes"])


def test_other_images_are_refused():
    other = EvalResult(
        paths=["a.png", "c.png"],
        keys=["a", "c"],
        confusions=np.asarray(ORACLE, dtype=np.int64),
        complexity={"delent": np.array([1.0, 2.0])},
        attributes={},
        classes=CLASSES,
        palette="p",
    )
    with pytest.raises(UsageError, match="the same images"):
        gap_closed(
            _table(SOURCE),
            [_table(ADAPTED)],
            other,
            ["s", "a", "o"],
            [],
            Bootstrap(resamples=0, cluster="image"),
        )


def _write_reports(folder):
    """Report folders of three models that score each of 4 images alike."""
    from claravid.eval.report.build import build_report
    from claravid.eval.report.folder import write_outputs

    names = {"src": SOURCE[0], "adapt": ADAPTED[0], "oracle": ORACLE[0]}
    for name, conf in names.items():
        table = EvalResult(
            paths=[f"{i}.png" for i in range(4)],
            keys=[str(i) for i in range(4)],
            confusions=np.asarray([conf] * 4, dtype=np.int64),
            complexity={"delent": np.arange(4.0)},
            attributes={},
            classes=CLASSES,
            palette="p",
            source={"kind": "predictions"},
        )
        report = build_report(table, bins=2, bootstrap=Bootstrap(resamples=100, cluster="image"))
        write_outputs(folder / name, report, table)


def test_compare_with_an_oracle_writes_gap_closed(tmp_path):
    """Report folders on disk, compared with --oracle: every image of each model alike, so each
    resample gives the same fraction: (0.775 - 0.6) / (1 - 0.6) = 0.4375, interval [0.4375,
    0.4375]."""
    from claravid.eval import compare

    _write_reports(tmp_path)
    text = compare(
        [tmp_path / "src", tmp_path / "adapt"],
        tmp_path / "cmp",
        Bootstrap(resamples=100),
        oracle=tmp_path / "oracle",
    )
    saved = json.loads((tmp_path / "cmp" / "compare.json").read_text())["gap_closed"]
    overall = saved["adapted"][0]["overall"]
    assert overall["closed"] == pytest.approx(0.4375)
    assert overall["closed_ci"] == pytest.approx([0.4375, 0.4375])
    assert [b["closed"] for b in saved["adapted"][0]["bins"]] == pytest.approx([0.4375] * 2)
    assert "Gap closed" in text and "0.44 [0.44, 0.44]" in text
    with pytest.raises(UsageError, match="at least one adapted"):
        compare([tmp_path / "src"], oracle=tmp_path / "oracle")


def test_compare_subcommand_takes_an_oracle(tmp_path, capsys):
    from claravid.eval.cli.evaluate import main

    _write_reports(tmp_path)
    src, adapt, oracle = (str(tmp_path / n) for n in ("src", "adapt", "oracle"))
    argv = ["compare", src, adapt, "--oracle", oracle, "--bootstrap", "100", "-o", f"{src}_cmp"]
    assert main(argv) == 0
    saved = json.loads((tmp_path / "src_cmp" / "compare.json").read_text())
    assert saved["gap_closed"]["adapted"][0]["classes"]["x"]["closed"] == pytest.approx(
        (4 / 5 - 3 / 5) / (1 - 3 / 5)
    )
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "src"), "--oracle", str(tmp_path / "oracle")]) == 2
    err = capsys.readouterr().err.strip()
    assert "at least one adapted report" in err and len(err.splitlines()) == 1


def test_merge_with_a_class_subset(tmp_path, capsys):
    """`--classes y` on a re-binning: every row also gets the mIoU over y alone (3/5)."""
    from claravid.eval.cli.evaluate import main

    _write_reports(tmp_path)
    src, out = str(tmp_path / "src"), str(tmp_path / "only_y")
    assert main(["merge", src, "--classes", "y", "--bootstrap", "100", "-o", out]) == 0
    report = json.loads((tmp_path / "only_y" / "report.json").read_text())
    assert report["overall"]["miou_classes"] == pytest.approx(3 / 5)
    assert report["source"]["classes_subset"] == ["y"]
    assert "## mIoU over y" in (tmp_path / "only_y" / "report.md").read_text()
    capsys.readouterr()
    assert main(["merge", src, "--classes", "y,z", "-o", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert "z not in the palette's classes" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "bad" / "report.json").exists()

"""Structural zeros: a class no ClaraVid class maps to, the mIoU cap it implies, mIoU over the
predictable classes, and comparisons that keep the two mIoUs apart. Hand-made confusions,
expected values worked out below."""

import numpy as np
import pytest

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.gaps import gap_analysis
from claravid.eval.analysis.miou_bins import stratify
from claravid.eval.analysis.table import EvalResult

CLASSES = ["A", "B", "F"]  # F: no source class, never predicted
# Image 1 holds A and F, image 2 only B (rows truth, columns prediction).
IMG1 = [[6, 2, 0], [0, 0, 0], [2, 2, 0]]
IMG2 = [[0, 0, 0], [1, 5, 0], [0, 0, 0]]
# Summed: IoU_A = 6 / (8 + 9 - 6) = 6/11, IoU_B = 5 / (6 + 9 - 5) = 1/2, IoU_F = 0 / 4 = 0.
ALL = (6 / 11 + 1 / 2 + 0) / 3
PREDICTABLE = (6 / 11 + 1 / 2) / 2
# Image 1 alone: IoU_A = 6 / (8 + 8 - 6) = 0.6, IoU_B = 0 / 2 = 0 -> 0.3; image 2 alone:
# IoU_A = 0 / 1 = 0, IoU_B = 5 / 6 -> 5/12.
ONE, TWO = 0.3, 5 / 12


def test_cap_and_predictable_miou_per_row():
    confusions = np.array([IMG1, IMG2])
    report = stratify(
        ["i1.png", "i2.png"],
        confusions,
        CLASSES,
        {"delent": np.array([1.0, 2.0])},
        bins=2,
        groups={"g1": [0], "g2": [1]},
        predictable=["A", "B"],
        bootstrap=Bootstrap(resamples=200, cluster="image"),
    )
    overall = report["overall"]
    assert overall["miou"] == pytest.approx(ALL)
    assert overall["miou_predictable"] == pytest.approx(PREDICTABLE)
    assert overall["miou_cap"] == pytest.approx(2 / 3)  # A, B, F present; F unpredictable
    assert overall["unpredictable_present"] == ["F"]
    # Two clusters: resamples are {1,1} (0.3), {2,2} (5/12) or {1,2} (the whole): the 95 %
    # interval reaches from 0.3 to the whole set's value.
    assert overall["miou_predictable_ci"] == pytest.approx([ONE, PREDICTABLE])
    g1, g2 = report["groups"]
    assert g1["miou_predictable"] == pytest.approx(ONE)
    assert g1["miou_cap"] == pytest.approx(1 / 2) and g1["unpredictable_present"] == ["F"]
    assert g2["miou_predictable"] == pytest.approx(TWO)
    assert g2["miou_cap"] == 1.0 and g2["unpredictable_present"] == []
    low, high = report["bins"]  # bins of one image each, in delentropy order
    assert low["miou_cap"] == pytest.approx(1 / 2) and high["miou_cap"] == 1.0


def test_nothing_added_when_every_class_is_predictable():
    report = stratify(["i1.png", "i2.png"], np.array([IMG1, IMG2]), CLASSES, predictable=CLASSES)
    assert "miou_cap" not in report["overall"] and "miou_predictable" not in report["overall"]


def test_markdown_states_the_structural_zero():
    from claravid.eval.report.transfer_text import predictable_section

    report = stratify(["i1.png", "i2.png"], np.array([IMG1, IMG2]), CLASSES, predictable=["A", "B"])
    report["source"] = {"predictable": ["A", "B"]}
    text = "\n".join(predictable_section(report))
    assert "No ClaraVid class maps to F" in text
    assert f"| **overall** | {ALL:.3f} | {PREDICTABLE:.3f} | 0.667 | F |" in text


def _result(confusions, predictable):
    return EvalResult(
        paths=["i1.png", "i2.png"],
        keys=["i1", "i2"],
        confusions=np.asarray(confusions, dtype=np.int64),
        complexity={"delent": np.array([1.0, 2.0])},
        attributes={},
        classes=CLASSES,
        palette="p",
        source={"predictable": predictable},
    )


def test_compare_keeps_the_predictable_gap_apart():
    """B: image 1 A [8,0,0], F [0,4,0]; image 2 B [0,6,0]. Summed: IoU_A = 1, IoU_B = 6/10,
    IoU_F = 0: mIoU 1.6/3 over all classes, 0.8 over A and B."""
    a = _result([IMG1, IMG2], ["A", "B"])
    b = _result([[[8, 0, 0], [0, 0, 0], [0, 4, 0]], [[0, 0, 0], [0, 6, 0], [0, 0, 0]]], ["A", "B"])
    reports = [{"source": {}, "bins": []}] * 2
    out = gap_analysis([a, b], reports, ["a", "b"], Bootstrap(resamples=0, cluster="image"))
    (entry,) = out["comparisons"]
    assert entry["overall"]["gap"] == pytest.approx(1.6 / 3 - ALL)
    assert entry["predictable"]["classes"] == ["A", "B"]
    assert entry["predictable"]["overall"]["gap"] == pytest.approx(0.8 - PREDICTABLE)
    assert entry["predictable"]["overall"]["paired"] is True
    # A report that does not say what is predictable (an older report): no subset gap.
    older = _result([IMG1, IMG2], None)
    out = gap_analysis([older, b], reports, ["a", "b"], Bootstrap(resamples=0, cluster="image"))
    assert out["comparisons"][0]["predictable"] is None


def test_a_chosen_subset_of_classes():
    from claravid.eval.settings import ReportSettings

    report = stratify(["i1.png", "i2.png"], np.array([IMG1, IMG2]), CLASSES, subset=["A", "B"])
    assert report["overall"]["miou_classes"] == pytest.approx(PREDICTABLE)
    assert "miou_cap" not in report["overall"]  # a subset states no structural zero
    report = stratify(["i1.png", "i2.png"], np.array([IMG1, IMG2]), CLASSES, subset=["B"])
    assert report["overall"]["miou_classes"] == pytest.approx(1 / 2)
    assert ReportSettings(classes=" A,,B ").classes == ["A", "B"]
    with pytest.raises(ValueError, match="Z not in the palette's classes"):
        stratify(["i1.png", "i2.png"], np.array([IMG1, IMG2]), CLASSES, subset=["A", "Z"])
    with pytest.raises(ValueError, match="--classes is empty"):
        ReportSettings(classes=",")

"""The label-budget curve from report folders: points, intervals, references, refusals."""

import json

import pytest
from matplotlib.image import imread

from claravid.eval.report.budget_curve import budget_curve, budget_markdown, budget_rows
from claravid.eval.report.files import REQUIRED_KEYS
from claravid.infra.cli import UsageError

CLASSES = ["Road", "Nature", "Person"]


def _report(folder, miou, ci, images=("a.png", "b.png", "c.png"), classes=CLASSES):
    """A report.json with the keys every report has; bins low and high of the same images."""
    folder.mkdir(parents=True)
    overall = {"num_images": len(images), "miou": miou, "miou_ci": ci, "ci_note": None}
    report = {key: None for key in REQUIRED_KEYS}
    report.update(
        overall=overall,
        bins=[
            {"name": "low", "miou": miou + 0.05, "miou_ci": [miou, miou + 0.1]},
            {"name": "high", "miou": miou - 0.05, "miou_ci": None},
        ],
        images=[{"path": p, "miou": miou} for p in images],
        classes=list(classes),
        palette="syndrone",
    )
    (folder / "report.json").write_text(json.dumps(report))
    return folder


def test_points_carry_each_report_mIoU_and_interval_in_budget_order(tmp_path):
    reports = {
        1.0: _report(tmp_path / "b100", 0.60, [0.55, 0.65]),
        0.01: _report(tmp_path / "b1", 0.30, [0.20, 0.41]),
        0.1: _report(tmp_path / "b10", 0.45, None),  # --bootstrap 0: no interval
    }
    source_only = _report(tmp_path / "src", 0.25, [0.21, 0.29])
    out = tmp_path / "curve.png"
    points = budget_curve(reports, out, references={"ClaraVid only": source_only}, bins=True)
    assert [p["budget"] for p in points] == [0.01, 0.1, 1.0]
    assert [p["name"] for p in points] == ["1 %", "10 %", "100 %"]
    assert [p["miou"] for p in points] == [0.30, 0.45, 0.60]
    assert [p["miou_ci"] for p in points] == [[0.20, 0.41], None, [0.55, 0.65]]
    assert points[0]["bins"][0] == {"name": "low", "miou": 0.35, "miou_ci": [0.30, 0.40]}
    picture = imread(out)
    assert picture.shape[0] > picture.shape[1]  # two panels: overall, then per bin
    points, lines = budget_rows(reports, {"ClaraVid only": source_only / "report.json"})
    table = budget_markdown(points, lines)
    assert "| 1 % | 3 | 0.300 [0.200, 0.410] |" in table
    assert "| 10 % | 3 | 0.450 |" in table
    assert "| ClaraVid only | 3 | 0.250 [0.210, 0.290] |" in table


@pytest.mark.parametrize("budget", [0, 1.5, -0.1])
def test_a_budget_outside_0_1_is_refused(tmp_path, budget):
    with pytest.raises(UsageError, match="not a fraction in"):
        budget_rows({budget: _report(tmp_path / "r", 0.5, None)})


def test_reports_of_other_images_or_classes_are_refused_by_name(tmp_path):
    base = _report(tmp_path / "b10", 0.4, None)
    other = _report(tmp_path / "b25", 0.5, None, images=("a.png", "b.png"))
    with pytest.raises(UsageError, match=r"b25.*other images than .*b10"):
        budget_rows({0.1: base, 0.25: other})
    classes = _report(tmp_path / "c25", 0.5, None, classes=["Road", "Nature", "Water"])
    with pytest.raises(UsageError, match=r"c25: its classes"):
        budget_rows({0.1: base, 0.25: classes})
    with pytest.raises(UsageError, match="not a claravid-eval report"):
        (tmp_path / "foreign").mkdir()
        (tmp_path / "foreign" / "report.json").write_text("{}")
        budget_rows({0.1: base, 1.0: tmp_path / "foreign"})

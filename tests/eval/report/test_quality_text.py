"""What a comparison prints of the measures beyond mIoU: a table when some bin has a gap, and
one line saying nothing was comparable when none has (never a table of dashes)."""

from claravid.eval.report.quality_text import quality_gap_lines


def _comparison(overall_gap, bin_gap):
    cell = {"gap": None, "gap_ci": None, "paired": True}
    return {
        "report": "b",
        "quality": {
            "consistency": {
                "overall": {"agreement": {**cell, "gap": overall_gap}, "tc": dict(cell)},
                "bins": [{"name": "low", "agreement": {**cell, "gap": bin_gap}, "tc": dict(cell)}],
            }
        },
    }


def test_a_comparison_with_no_value_in_both_reports_says_so_in_one_line():
    lines = quality_gap_lines(_comparison(None, None), "a")
    assert "|" not in "".join(lines)  # no table
    said = [ln for ln in lines if "not compared" in ln]
    assert said == [
        "- Cross-view consistency not compared: no bin has a value in both reports (no pair, "
        "or no pixel, measured in one of them)"
    ]


def test_one_gap_anywhere_keeps_the_table():
    lines = quality_gap_lines(_comparison(None, 0.25), "a")
    text = "\n".join(lines)
    assert "Cross-view consistency: b − a, paired:" in text
    assert "+0.250" in text and "not compared" not in text

"""The measures beyond mIoU as text: ``report.md``'s sections, the printed table, the gaps of a
comparison.

Each measure that a report computed gets a table per complexity bin (with the bootstrap
intervals where the report has them); one that it did not says why in one line.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from claravid.eval.report.cells import bin_range, md_table, number, with_ci

TITLES = {
    "boundary_iou": "Boundary IoU",
    "calibration": "Calibration",
    "consistency": "Cross-view consistency",
}
#: What the comparison tables call each compared statistic, and which way is better.
STATISTIC_NAMES = {
    "miou": ("mBoundaryIoU", "higher is better"),
    "ece": ("ECE", "lower is better"),
    "mce": ("MCE", "lower is better"),
    "agreement": ("consistency", "higher is better"),
    "tc": ("TC", "higher is better"),
}


def status_line(name: str, entry: dict[str, Any] | None) -> str | None:
    """``- calibration: unavailable (label maps have no scores)``; None when computed."""
    entry = entry or {"status": "absent", "reason": "not in this report"}
    if entry.get("status") == "computed":
        return None
    reason = f" ({entry['reason']})" if entry.get("reason") else ""
    return f"- {TITLES[name]}: {entry.get('status')}{reason}"


def _rows(report: dict[str, Any]) -> list[dict[str, Any]]:
    return [*report["bins"], {"name": "**overall**", **report["overall"]}]


def _boundary(report: dict[str, Any]) -> list[str]:
    rows = [[r["name"], bin_range(r) if r["name"] != "**overall**" else "", str(r["num_images"]),
             with_ci(r["boundary_iou"]["miou"], r["boundary_iou"].get("miou_ci")),
             number(r["miou"])] for r in _rows(report)]  # fmt: skip
    settings = report["quality"]["boundary_iou"].get("settings") or {}
    note = (f"Boundary IoU (Cheng et al. 2021): per class, the boundary pixels of ground truth and "
            f"prediction within d = max(1, round({settings.get('dilation_ratio', 0.02)} · image "
            "diagonal)) pixels of the mask's edge; a group's IoU from its summed intersections "
            "and unions; mBoundaryIoU the NaN-mean over classes.")  # fmt: skip
    return [note, "", *md_table(["bin", "delentropy", "images", "mBoundaryIoU", "mIoU"], rows)]


def _calibration(report: dict[str, Any]) -> list[str]:
    rows = []
    for r in _rows(report):
        c = r["calibration"]
        rows.append([r["name"], str(c["num_pixels"]), with_ci(c["ece"], c.get("ece_ci")),
                     with_ci(c["mce"], c.get("mce_ci"))])  # fmt: skip
    settings = report["quality"]["calibration"].get("settings") or {}
    note = (f"Confidence = the largest softmax probability of a pixel's logits; "
            f"{settings.get('bins', 15)} equal-width confidence bins; ECE = Σ n_b/N · |acc_b − "
            "conf_b| over valid pixels, MCE = the largest |acc_b − conf_b| of a non-empty bin "
            "(lower is better).")  # fmt: skip
    return [note, "", *md_table(["bin", "pixels", "ECE", "MCE"], rows)]


def _consistency(report: dict[str, Any]) -> list[str]:
    rows = []
    for r in _rows(report):
        c = r["consistency"]
        pairs = c["pairs"]
        rows.append([r["name"], str(pairs["ok"]), str(pairs["turn"]), str(c["kept_pixels"]),
                     with_ci(c["agreement"], c.get("agreement_ci")),
                     with_ci(c["agreement_gt"], c.get("agreement_gt_ci")),
                     number(c["tc"]), number(c["tc_gt"])])  # fmt: skip
    entry = report["quality"]["consistency"]
    counts = entry.get("pairs") or {}
    note = ("Each frame t is paired with the next frame s of its pass; a pixel of t is carried "
            "to s through its depth and the two poses and kept when it lands inside s, is "
            "static, labelled in both and visible in s (depth test). Consistency = kept pixels "
            "whose predictions agree / kept pixels; TC = mean over classes of the IoU of the "
            "two predictions; the same on the ground truth is the ceiling. A pair belongs to "
            "frame t's bin; pairs with under 10 % of the frame kept (a turn) are "
            "skipped.")  # fmt: skip
    lines = [note, ""]
    lines += md_table(["bin", "pairs", "skipped (turn)", "kept pixels", "consistency",
                     "ground truth (ceiling)", "TC", "TC ground truth"], rows)  # fmt: skip
    other = {k: v for k, v in counts.items() if k not in ("ok", "turn") and v}
    if other:
        listed = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in other.items())
        example = f" (e.g. {entry['unavailable'][0]})" if entry.get("unavailable") else ""
        lines += [f"Not counted: {listed}{example}.", ""]
    return lines


SECTIONS = {"boundary_iou": _boundary, "calibration": _calibration, "consistency": _consistency}


def quality_sections(report: dict[str, Any]) -> list[str]:
    """``report.md``'s sections of the measures beyond mIoU, with one line per measure not
    computed (a report written before them says so)."""
    summary = report.get("quality")
    if not isinstance(summary, dict):
        return ["## Beyond mIoU", "",
                "- not measured: the report was written before Boundary IoU, calibration and "
                "consistency existed", ""]  # fmt: skip
    lines = []
    missing = [line for name in SECTIONS if (line := status_line(name, summary.get(name)))]
    for name, section in SECTIONS.items():
        if (summary.get(name) or {}).get("status") == "computed":
            lines += [f"## {TITLES[name]} per complexity bin", "", *section(report)]
    if missing:
        lines += ["## Not measured", "", *missing, ""]
    return lines


def quality_table(report: dict[str, Any]) -> str:
    """The measures per bin as aligned plain text (what the command prints), '' when none."""
    summary = report.get("quality") or {}
    shown = [n for n in SECTIONS if (summary.get(n) or {}).get("status") == "computed"]
    if not shown:
        return ""
    heads = {"boundary_iou": "mBoundaryIoU", "calibration": "ECE",
             "consistency": "consistency (GT)"}  # fmt: skip
    lines = [f"{'bin':<16}" + "".join(f"{heads[n]:>26}" for n in shown)]
    for row in [*report["bins"], {"name": "overall", **report["overall"]}]:
        cells = []
        for n in shown:
            e = row[n]
            if n == "boundary_iou":
                cells.append(with_ci(e["miou"], e.get("miou_ci")))
            elif n == "calibration":
                cells.append(with_ci(e["ece"], e.get("ece_ci")))
            else:
                cells.append(f"{number(e['agreement'])} ({number(e['agreement_gt'])})")
        lines.append(f"{row['name']:<16}" + "".join(f"{c:>26}" for c in cells))
    return "\n".join(lines)


def _gap(row: dict[str, Any], digits: int = 3) -> str:
    if row.get("gap") is None:
        return "–"
    text = f"{row['gap']:+.{digits}f}"
    ci = row.get("gap_ci")
    if ci:
        text += f" [{ci[0]:+.{digits}f}, {ci[1]:+.{digits}f}]"
        text += " **excludes 0**" if ci[0] > 0 or ci[1] < 0 else ""
    return text


def quality_gap_lines(comp: dict[str, Any], baseline: str) -> list[str]:
    """A comparison's gaps of the measures beyond mIoU, one table per measure, and what could
    not be compared."""
    lines, nothing = [], []
    for measure, gaps in (comp.get("quality") or {}).items():
        names = [n for n in gaps["overall"] if isinstance(gaps["overall"][n], dict)]
        cells = [row[n] for row in (*gaps["bins"], gaps["overall"]) for n in names]
        if all(cell.get("gap") is None for cell in cells):  # a table of dashes says nothing
            nothing.append(f"- {TITLES[measure]} not compared: no bin has a value in both "
                           "reports (no pair, or no pixel, measured in one of them)")  # fmt: skip
            continue
        header = ["bin", *[f"{STATISTIC_NAMES[n][0]} gap ({STATISTIC_NAMES[n][1]})"
                           for n in names]]  # fmt: skip
        rows = [[b["name"], *[_gap(b[n]) for n in names]] for b in gaps["bins"]]
        rows.append(["**overall**", *[_gap(gaps["overall"][n]) for n in names]])
        kind = "paired" if gaps["overall"][names[0]].get("paired") else "unpaired"
        lines += [f"{TITLES[measure]}: {comp['report']} − {baseline}, {kind}:", ""]
        lines += md_table(header, rows)
    for measure, why in (comp.get("missing") or {}).items():
        lines.append(f"- {TITLES[measure]} not compared: {why}")
    lines += nothing
    return [*lines, ""] if comp.get("missing") or nothing else lines


def missing_everywhere(reports: Sequence[dict[str, Any]], names: Sequence[str]) -> list[str]:
    """Without ``compare.json`` (no confusions): which measures each report lacks."""
    out = []
    for report, name in zip(reports, names, strict=True):
        summary = report.get("quality")
        if not isinstance(summary, dict):
            out.append(f"{name}: no measure beyond mIoU (written before they existed)")
            continue
        lacking = [
            TITLES[n] for n in SECTIONS if (summary.get(n) or {}).get("status") != "computed"
        ]
        if lacking:
            out.append(f"{name}: {', '.join(lacking)} not measured")
    return out

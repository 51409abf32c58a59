"""The report as text: ``report.md``, the bin table printed at the end of a run, comparisons."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

HARDEST_TABLE = 10


def _f(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def _range(row: dict[str, Any]) -> str:
    return f"[{_f(row.get('lo'), 2)}, {_f(row.get('hi'), 2)}]"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return [*lines, *("| " + " | ".join(row) + " |" for row in rows), ""]


def bin_table(report: dict[str, Any]) -> str:
    """The bins and the overall row as aligned plain text (what the command prints)."""
    lines = [f"{'bin':<16}{'delentropy':>18}{'images':>8}{'mIoU':>8}{'pix acc':>9}"]
    for row in [*report["bins"], {"name": "overall", **report["overall"]}]:
        span = _range(row) if row["name"] != "overall" else ""
        lines.append(
            f"{row['name']:<16}{span:>18}{row['num_images']:>8}{_f(row['miou']):>8}"
            f"{_f(row['pixel_acc']):>9}"
        )
    return "\n".join(lines)


def report_markdown(report: dict[str, Any], plots: dict[str, str]) -> str:
    """``report.md``: source, conventions, bins, groups, per-class IoU, correlations, plots."""
    source, classes = report["source"], report["classes"]
    binning = source.get("binning", {})
    lines = ["# Evaluation report", ""]
    what = source.get("kind", "?")
    origin = (
        source.get("path") or source.get("predictions") or ", ".join(source.get("merged_from", []))
    )
    lines.append(f"- source: {what} `{origin}`")
    if source.get("data"):
        lines.append(
            f"- data: {source.get('dataset')} `{source['data']}`, split {source.get('split')}"
        )
    lines.append(f"- palette: {report['palette']} ({len(classes)} classes), ignore index "
                 f"{report['ignore_index']}")  # fmt: skip
    method = binning.get("method")
    if method == "fixed":
        lines.append(f"- bins: fixed delentropy edges {binning.get('edges')}")
    elif method:
        lines.append(f"- bins: {binning.get('bins')} quantile bins of delentropy")
    if binning.get("outside"):
        lines.append(f"- {len(binning['outside'])} image(s) outside the fixed edges (in no bin)")
    skipped = source.get("skipped") or []
    if skipped:
        lines.append(f"- {len(skipped)} image(s) skipped (no prediction): "
                     + ", ".join(f"`{s}`" for s in skipped[:5]))  # fmt: skip
    lines += ["", f"**Conventions.** {report['convention']} Complexity = delentropy (DSP recipe, "
              "3×3 Gaussian blur σ=1) of the RGB file; quantile bins split the images sorted by "
              "(delentropy, path) like numpy.array_split; fixed edges are [e_i, e_i+1), the last "
              "closed. Correlations: Pearson and Spearman between per-image complexity and "
              "per-image mIoU.", ""]  # fmt: skip

    lines += ["## mIoU per complexity bin", ""]
    rows = [[r["name"], _range(r), str(r["num_images"]), _f(r["miou"]), _f(r["pixel_acc"])]
            for r in report["bins"]]  # fmt: skip
    overall = report["overall"]
    rows.append(["**overall**", "", str(overall["num_images"]), _f(overall["miou"]),
                 _f(overall["pixel_acc"])])  # fmt: skip
    lines += _table(["bin", "delentropy", "images", "mIoU", "pixel acc"], rows)

    if report["groups"]:
        lines += [f"## Per {binning.get('group_by') or 'group'}", ""]
        rows = []
        for g in report["groups"]:
            p = g.get("profile") or {}
            rows.append([g["name"], str(g["num_images"]), _f(p.get("mu")), _f(p.get("alpha"), 2),
                         _f(p.get("beta"), 2), _f(g["miou"]), _f(g["pixel_acc"])])  # fmt: skip
        lines += _table(["group", "images", "DSP μ", "α", "β", "mIoU", "pixel acc"], rows)

    lines += ["## IoU per class", ""]
    header = ["class", "overall", *[r["name"] for r in report["bins"]]]
    rows = [[c, _f(overall["per_class_iou"][c]),
             *[_f(r["per_class_iou"][c]) for r in report["bins"]]] for c in classes]  # fmt: skip
    lines += _table(header, rows)

    lines += ["## Complexity vs accuracy", ""]
    rows = [[m, _f(c["pearson"]), _f(c["spearman"]), str(c["n"])]
            for m, c in report["correlation"].items()]  # fmt: skip
    lines += _table(["measure", "Pearson r", "Spearman ρ", "n"], rows)

    hardest = sorted(
        (r for r in report["images"] if r["miou"] is not None), key=lambda r: r["miou"]
    )[:HARDEST_TABLE]
    if hardest:
        lines += ["## Hardest images", ""]
        rows = [[f"`{r['path']}`", _f(r.get("delent")), _f(r["miou"]), _f(r["pixel_acc"])]
                for r in hardest]  # fmt: skip
        lines += _table(["image", "delentropy", "mIoU", "pixel acc"], rows)

    if plots:
        lines += ["## Plots", ""]
        lines += [f"![{name}]({file})" for name, file in plots.items()] + [""]
    return "\n".join(lines)


def compare_markdown(
    reports: Sequence[dict[str, Any]], names: Sequence[str], warnings: Sequence[str]
) -> str:
    """Bin tables side by side: one row per bin (matched by position), one column per report."""
    lines = ["# Comparison", ""]
    lines += [f"- **{n}**: palette {r['palette']}, {r['overall']['num_images']} images"
              for n, r in zip(names, reports, strict=True)]  # fmt: skip
    lines += [f"- warning: {w}" for w in warnings] + [""]
    n_bins = max(len(r["bins"]) for r in reports)
    header = ["bin"] + [f"{n} {col}" for n in names for col in ("range", "n", "mIoU")]
    rows = []
    for i in range(n_bins):
        row = [next((r["bins"][i]["name"] for r in reports if i < len(r["bins"])), str(i))]
        for report in reports:
            if i < len(report["bins"]):
                b = report["bins"][i]
                row += [_range(b), str(b["num_images"]), _f(b["miou"])]
            else:
                row += ["", "", ""]
        rows.append(row)
    overall = ["**overall**"]
    for report in reports:
        overall += ["", str(report["overall"]["num_images"]), _f(report["overall"]["miou"])]
    lines += _table(header, [*rows, overall])
    if len(reports) >= 2:
        lines += [f"Gap {names[1]} − {names[0]} per bin (mIoU points):", ""]
        gaps = []
        for i in range(n_bins):
            a = reports[0]["bins"][i]["miou"] if i < len(reports[0]["bins"]) else None
            b = reports[1]["bins"][i]["miou"] if i < len(reports[1]["bins"]) else None
            gaps.append([rows[i][0], _f(None if a is None or b is None else 100 * (b - a), 1)])
        lines += _table(["bin", "gap"], gaps)
    return "\n".join(lines)

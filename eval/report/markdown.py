"""The report as text: ``report.md``, the bin table printed at the end of a run, comparisons."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

HARDEST_TABLE = 10


def number(value: float | None, digits: int = 3) -> str:
    """``0.357``; ``–`` for a missing value."""
    return "–" if value is None else f"{value:.{digits}f}"


def with_ci(value: float | None, ci: Sequence[float] | None, digits: int = 3) -> str:
    """``0.357 [0.331, 0.384]``; the value alone when there is no interval."""
    if value is None or not ci:
        return number(value, digits)
    return f"{value:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def uncertainty_line(unc: dict[str, Any] | None) -> str | None:
    """How the intervals were made, for a report's header (None: no intervals)."""
    if not unc:
        return None
    if not unc.get("resamples"):
        return "- intervals: off (--bootstrap 0)"
    return (
        f"- intervals: {unc['level']:.0%} {unc['method']}, {unc['resamples']} resamples of "
        f"{unc['num_clusters']} {unc['cluster']} clusters, seed {unc['seed']}"
    )


def bin_range(row: dict[str, Any]) -> str:
    """A bin's delentropy range, ``[3.10, 4.20]``."""
    return f"[{number(row.get('lo'), 2)}, {number(row.get('hi'), 2)}]"


def md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A Markdown table's lines, then a blank line."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return [*lines, *("| " + " | ".join(row) + " |" for row in rows), ""]


def bin_table(report: dict[str, Any]) -> str:
    """The bins and the overall row as aligned plain text (what the command prints); with
    tiles, the tile bins below."""
    lines = [f"{'bin':<16}{'delentropy':>18}{'images':>8}{'mIoU':>24}{'pix acc':>9}"]
    for row in [*report["bins"], {"name": "overall", **report["overall"]}]:
        span = bin_range(row) if row["name"] != "overall" else ""
        miou = with_ci(row["miou"], row.get("miou_ci"))
        lines.append(
            f"{row['name']:<16}{span:>18}{row['num_images']:>8}{miou:>24}{number(row['pixel_acc']):>9}"
        )
    tiles = report.get("tiles")
    if tiles:
        lines += ["", f"{'tile bin':<16}{'delentropy':>18}{'tiles':>8}{'mIoU':>24}{'pix acc':>9}"]
        for row in tiles["bins"]:
            miou = with_ci(row["miou"], row.get("miou_ci"))
            lines.append(f"{row['name']:<16}{bin_range(row):>18}{row['num_tiles']:>8}{miou:>24}"
                         f"{number(row['pixel_acc']):>9}")  # fmt: skip
        c = tiles["correlation"]["delent"]
        rho = with_ci(c["spearman"], c.get("spearman_ci"))
        lines.append(f"tiles of about {tiles['size']} px: Spearman ρ (tile delentropy, tile "
                     f"mIoU) {rho}, n = {c['n']}")  # fmt: skip
    return "\n".join(lines)


def report_markdown(report: dict[str, Any], plots: dict[str, str]) -> str:
    """``report.md``: source, conventions, bins, groups, per-class IoU, correlations, the
    measures beyond mIoU, the hardest images, plots."""
    # The measures' sections format with this module's helpers: imported here, not at the top.
    from claravid.eval.report.quality_text import quality_sections

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
    chosen = source.get("selection")
    if chosen:
        split = chosen.get("split_config") or {}
        lines.append(
            f"- frames: missions {', '.join(chosen['missions'])}; altitude "
            f"{', '.join(chosen.get('altitude') or ['all'])}; direction "
            f"{', '.join(chosen.get('direction') or ['all'])}; split blocks of "
            f"{split.get('block_size')} m, fractions {split.get('fractions')}, seed "
            f"{split.get('seed')}"
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
    line = uncertainty_line(report.get("uncertainty"))
    if line:
        lines.append(line)
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
    rows = [[r["name"], bin_range(r), str(r["num_images"]), *_scores(r)] for r in report["bins"]]
    overall = report["overall"]
    rows.append(["**overall**", "", str(overall["num_images"]), *_scores(overall)])
    lines += md_table(["bin", "delentropy", "images", "mIoU", "pixel acc"], rows)
    lines += _warnings(report)

    if report["groups"]:
        lines += [f"## Per {binning.get('group_by') or 'group'}", ""]
        rows = []
        for g in report["groups"]:
            p = g.get("profile") or {}
            rows.append([g["name"], str(g["num_images"]), number(p.get("mu")),
                         _shape(p, "alpha", 2), _shape(p, "beta", 2), *_scores(g)])  # fmt: skip
        lines += md_table(["group", "images", "DSP μ", "α", "β", "mIoU", "pixel acc"], rows)
        lines += _profile_notes(report["groups"])

    lines += ["## IoU per class", ""]
    header = ["class", "overall", *[r["name"] for r in report["bins"]]]
    rows = [[c, number(overall["per_class_iou"][c]),
             *[number(r["per_class_iou"][c]) for r in report["bins"]]]
            for c in classes]  # fmt: skip
    lines += md_table(header, rows)

    lines += ["## Complexity vs accuracy", ""]
    rows = [[m, with_ci(c["pearson"], c.get("pearson_ci")),
             with_ci(c["spearman"], c.get("spearman_ci")), str(c["n"])]
            for m, c in report["correlation"].items()]  # fmt: skip
    lines += md_table(["measure", "Pearson r", "Spearman ρ", "n"], rows)

    lines += tile_section(report.get("tiles"))
    lines += quality_sections(report)

    hardest = sorted(
        (r for r in report["images"] if r["miou"] is not None), key=lambda r: r["miou"]
    )[:HARDEST_TABLE]
    if hardest:
        lines += ["## Hardest images", ""]
        rows = [[f"`{r['path']}`", number(r.get("delent")), number(r["miou"]),
                 number(r["pixel_acc"])] for r in hardest]  # fmt: skip
        lines += md_table(["image", "delentropy", "mIoU", "pixel acc"], rows)

    if plots:
        lines += ["## Plots", ""]
        lines += [f"![{name}]({file})" for name, file in plots.items()] + [""]
    return "\n".join(lines)


def tile_section(tiles: dict[str, Any] | None) -> list[str]:
    """``report.md``'s tile section (``--tiles``): mIoU per tile bin, the tile correlation."""
    if not tiles:
        return []
    lines = [f"## Tiles of about {tiles['size']} px", ""]
    lines.append(
        f"{tiles['num_tiles']} tiles, each with its own delentropy (the DSP recipe on the tile's "
        "pixels) and its own confusion; bins over tiles sorted by (delentropy, path, row, "
        "column); a tile is resampled with its image's cluster."
        + (f" {tiles['num_without_labels']} tile(s) without a valid pixel are left out of the "
           "correlation." if tiles.get("num_without_labels") else "")
    )  # fmt: skip
    lines.append("")
    rows = [[r["name"], bin_range(r), str(r["num_tiles"]), *_scores(r)] for r in tiles["bins"]]
    lines += md_table(["tile bin", "delentropy", "tiles", "mIoU", "pixel acc"], rows)
    c = tiles["correlation"]["delent"]
    lines += [
        f"Tile delentropy vs the tile's own mIoU: Pearson r "
        f"{with_ci(c['pearson'], c.get('pearson_ci'))}, Spearman ρ "
        f"{with_ci(c['spearman'], c.get('spearman_ci'))}, n = {c['n']}.",
        "",
    ]
    return lines


def _shape(profile: dict[str, Any], key: str, digits: int = 3) -> str:
    """α or β of a group's profile: "n/a" where the Beta fit says nothing (see its note)."""
    value = profile.get(key)
    return "n/a" if value is None and profile.get("mu") is not None else number(value, digits)


def _profile_notes(groups: Sequence[dict[str, Any]]) -> list[str]:
    """Why a group's α and β are n/a, one line per group."""
    notes = [f"- {g['name']}: α, β n/a ({g['profile']['note']})"
             for g in groups if (g.get("profile") or {}).get("note")]  # fmt: skip
    return [*notes, ""] if notes else []


def _scores(row: dict[str, Any]) -> list[str]:
    """mIoU and pixel accuracy cells, with their intervals when there are any."""
    return [with_ci(row["miou"], row.get("miou_ci")),
            with_ci(row["pixel_acc"], row.get("pixel_acc_ci"))]  # fmt: skip


def _warnings(report: dict[str, Any]) -> list[str]:
    unc = report.get("uncertainty") or {}
    rows = report["bins"] if unc.get("resamples") else []
    notes = [f"- {r['name']}: no interval ({r['ci_note']})" for r in rows if r.get("ci_note")]
    messages = unc.get("warnings", [])
    out = [f"**Warning:** {m}." for m in messages]
    return [*notes, *out, ""] if notes or out else []


def compare_markdown(
    reports: Sequence[dict[str, Any]],
    names: Sequence[str],
    warnings: Sequence[str],
    analysis: dict[str, Any] | None = None,
    note: str | None = None,
) -> str:
    """Bin tables side by side: one row per bin (matched by position), one column per report;
    with ``analysis`` (``compare.json``), each report's gap to the baseline with intervals;
    ``note`` says why there is none."""
    lines = ["# Comparison", ""]
    lines += [f"- **{n}**: palette {r['palette']}, {r['overall']['num_images']} images"
              for n, r in zip(names, reports, strict=True)]  # fmt: skip
    lines += [f"- warning: {w}" for w in warnings]
    lines += ([f"- note: {note}"] if note else []) + [""]
    n_bins = max(len(r["bins"]) for r in reports)
    header = ["bin"] + [f"{n} {col}" for n in names for col in ("range", "n", "mIoU")]
    rows = []
    for i in range(n_bins):
        row = [next((r["bins"][i]["name"] for r in reports if i < len(r["bins"])), str(i))]
        for report in reports:
            if i < len(report["bins"]):
                b = report["bins"][i]
                row += [bin_range(b), str(b["num_images"]), number(b["miou"])]
            else:
                row += ["", "", ""]
        rows.append(row)
    overall = ["**overall**"]
    for report in reports:
        overall += ["", str(report["overall"]["num_images"]), number(report["overall"]["miou"])]
    lines += md_table(header, [*rows, overall])
    if analysis is not None:
        return "\n".join(lines + _gap_tables(analysis))
    from claravid.eval.report.quality_text import missing_everywhere

    lacking = missing_everywhere(reports, names)
    lines += [f"- {line}" for line in lacking] + ([""] if lacking else [])
    if len(reports) >= 2:
        lines += [f"Gap {names[1]} − {names[0]} per bin (mIoU points):", ""]
        gaps = []
        for i in range(n_bins):
            a = reports[0]["bins"][i]["miou"] if i < len(reports[0]["bins"]) else None
            b = reports[1]["bins"][i]["miou"] if i < len(reports[1]["bins"]) else None
            gap = None if a is None or b is None else 100 * (b - a)
            gaps.append([rows[i][0], number(gap, _points_digits([gap]))])
        lines += md_table(["bin", "gap"], gaps)
    return "\n".join(lines)


def _points_digits(values: Sequence[float | None], most: int = 4) -> int:
    """Decimals for gaps in mIoU points: 1, or as many as the smallest non-zero value needs to
    show its first significant digit (at most ``most``), so that a gap of 0.003 points with an
    interval that excludes 0 is not written ``+0.0 [+0.0, +0.0]``."""
    small = min((abs(v) for v in values if v), default=None)
    if small is None or small >= 0.05:
        return 1
    return min(most, max(1, math.ceil(-math.log10(small))))


def _p(p: float | None, resamples: int) -> str:
    """A p-value; 0 (no resample on the other side) is written as below 1/R."""
    if p is None:
        return "–"
    return f"< {1 / resamples:.2g}" if p == 0 and resamples else f"{p:.3f}"


def _gap_cell(row: dict[str, Any], resamples: int) -> list[str]:
    """Gap in mIoU points with its interval, the p-value, and a mark when 0 is outside."""
    gap, ci = row.get("gap"), row.get("gap_ci")
    if gap is None:
        return ["–", "–", ""]
    points = [100 * v for v in (gap, *(ci or []))]
    d = _points_digits(points)
    text = f"{points[0]:+.{d}f}"
    if ci:
        text += f" [{points[1]:+.{d}f}, {points[2]:+.{d}f}]"
    p = row.get("p_value")
    if not ci:  # no interval (--bootstrap 0, too few clusters): nothing to exclude
        return [text, _p(p, resamples), "–"]
    excludes = ci[0] > 0 or ci[1] < 0
    return [text, _p(p, resamples), "**yes**" if excludes else "no"]


def _gap_tables(analysis: dict[str, Any]) -> list[str]:
    """One table per compared report: gap B − A overall and per bin, interval, p-value; then
    the gaps of the measures beyond mIoU."""
    from claravid.eval.report.quality_text import quality_gap_lines

    unc = analysis["uncertainty"]
    lines = [uncertainty_line(unc) or "", ""]
    for comp in analysis["comparisons"]:
        if comp.get("comparable") is False:
            lines += [f"Gap {comp['report']} − {analysis['baseline']}: **not comparable**: "
                      f"{comp['reason']}; no gaps or p-values computed.", ""]  # fmt: skip
            continue
        kind = "paired (same images, same resampled clusters)" if comp["paired"] else (
            "unpaired (different images, resampled independently)")  # fmt: skip
        lines += [f"Gap {comp['report']} − {analysis['baseline']} in mIoU points, {kind}; "
                  f"**yes** = the {unc['level']:.0%} interval excludes 0:", ""]  # fmt: skip
        r = unc["resamples"]
        rows = [[b["name"], *_gap_cell(b, r)] for b in comp["bins"]]
        rows.append(["**overall**", *_gap_cell(comp["overall"], r)])
        lines += md_table(["bin", "gap [interval]", "p-value", "interval excludes 0"], rows)
        lines += quality_gap_lines(comp, analysis["baseline"])
    return lines


def metric_markdown(report: dict[str, Any], plots: dict[str, str]) -> str:
    """``report.md`` of a ``scores`` report: bins, groups (paper Table 5 layout: DSP μ, σ,
    α, β next to the metric means, rows sorted by μ), correlations (Fig. 6), plots."""
    source, metrics = report["source"], report["metrics"]
    binning = source.get("binning", {})
    lines = ["# Complexity vs per-image metrics", ""]
    lines.append(f"- scores: `{source.get('scores')}` ({', '.join(metrics)})")
    lines.append(f"- data: {source.get('dataset')} `{source.get('data')}`, split "
                 f"{source.get('split')}")  # fmt: skip
    line = uncertainty_line(report.get("uncertainty"))
    if line:
        lines.append(line)
    if binning.get("method") == "fixed":
        lines.append(f"- bins: fixed delentropy edges {binning.get('edges')}")
    elif binning.get("method"):
        lines.append(f"- bins: {binning.get('bins')} quantile bins of delentropy")
    lines += ["", f"**Conventions.** {report['convention']}", ""]

    def cells(row: dict[str, Any]) -> list[str]:
        return [with_ci(row["scores"][m]["mean"], row["scores"][m]["ci"]) for m in metrics]

    lines += ["## Mean per complexity bin", ""]
    rows = [[r["name"], bin_range(r), str(r["num_images"]), *cells(r)] for r in report["bins"]]
    rows.append(["**overall**", "", str(report["overall"]["num_images"]),
                 *cells(report["overall"])])  # fmt: skip
    lines += md_table(["bin", "delentropy", "images", *metrics], rows)
    warnings = (report.get("uncertainty") or {}).get("warnings", [])
    lines += [f"**Warning:** {m}." for m in warnings] + ([""] if warnings else [])

    if report["groups"]:
        lines += [f"## Per {binning.get('group_by') or 'group'} (sorted by DSP μ)", ""]
        groups = sorted(report["groups"],
                        key=lambda g: ((g.get("profile") or {}).get("mu") is None,
                                       (g.get("profile") or {}).get("mu") or 0.0))  # fmt: skip
        rows = []
        for g in groups:
            p = g.get("profile") or {}
            rows.append([g["name"], str(g["num_images"]), number(p.get("mu")),
                         number(p.get("sigma")), _shape(p, "alpha"), _shape(p, "beta"),
                         *cells(g)])  # fmt: skip
        lines += md_table(["group", "images", "DSP μ", "σ", "α", "β", *metrics], rows)
        lines += _profile_notes(groups)

    lines += ["## Correlations", ""]
    rows = []
    for measure, by_metric in report["correlation"].items():
        for metric, c in by_metric.items():
            rows.append([measure, metric, with_ci(c["pearson"], c.get("pearson_ci")),
                         with_ci(c["spearman"], c.get("spearman_ci")), str(c["n"])])  # fmt: skip
    lines += md_table(["measure", "metric", "Pearson r", "Spearman ρ", "n"], rows)
    if plots:
        lines += ["## Plots", ""]
        lines += [f"![{name}]({file})" for name, file in plots.items()] + [""]
    return "\n".join(lines)

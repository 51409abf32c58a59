"""The label-budget curve: mIoU against the share of labelled training images, with intervals.

One ``claravid-eval`` report per budget, all on the same images and palette (the runs of
``claravid-train ... data.budget=F model.init=...``, evaluated alike)::

    from claravid.eval.report.budget_curve import budget_curve
    rows = budget_curve({0.01: "runs/b01/report", 0.1: "runs/b10/report", 1.0: "runs/b100/report"},
                        "budget_curve.png", references={"ClaraVid only": "runs/claravid/report"})

Each point is a report's overall mIoU with its bootstrap interval (``overall.miou_ci``, as the
report carries it); with ``bins=True`` a second panel draws the mIoU of each complexity bin.
``references`` (a model trained without any real label, or a target-only one) are drawn as
horizontal lines with their interval as a band. Reports that cover other images, another
palette or other classes are refused by name: their numbers are not points of one curve.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from claravid.eval.report.files import read_report
from claravid.eval.report.markdown import md_table, with_ci
from claravid.eval.report.plots import error_bars, save_figure
from claravid.infra.cli import UsageError


def _report(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    return read_report(path / "report.json" if path.is_dir() else path)


def _same_data(reports: Mapping[str, dict[str, Any]]) -> None:
    """Every report scores the same images with the same palette and classes.

    Raises:
        UsageError: naming the first report that differs from the first one, and in what.
    """
    (first_name, first), *others = reports.items()
    paths = sorted(row["path"] for row in first["images"])
    for name, report in others:
        for key in ("palette", "classes"):
            if report[key] != first[key]:
                raise UsageError(
                    f"{name}: its {key} ({report[key]}) is not {first_name}'s ({first[key]}); "
                    "a budget curve compares reports of one palette"
                )
        if sorted(row["path"] for row in report["images"]) != paths:
            raise UsageError(
                f"{name}: it scores other images than {first_name} ({len(report['images'])} "
                f"against {len(paths)}); evaluate every budget on the same data and split"
            )


def budget_rows(
    reports: Mapping[float, str | Path], references: Mapping[str, str | Path] | None = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The curve's points and reference lines, read from report folders (or their JSON).

    Args:
        reports: budget (a fraction in (0, 1]) -> report folder.
        references: name -> report folder, drawn as horizontal lines.

    Returns:
        ``(points, references)``: rows with ``budget`` (points only), ``name``, ``miou``,
        ``miou_ci``, ``num_images`` and ``bins`` (``name``, ``miou``, ``miou_ci`` per bin).

    Raises:
        UsageError: no report, a budget outside (0, 1], a file that is no report, reports of
            other images, palettes or classes.
    """
    if not reports:
        raise UsageError("a budget curve needs at least one report (budget -> report folder)")
    bad = [b for b in reports if not (isinstance(b, int | float) and 0 < b <= 1)]
    if bad:
        raise UsageError(f"budget {bad[0]!r} is not a fraction in (0, 1] (0.1 for 10 %)")
    read = {str(path): _report(path) for path in [*reports.values(), *(references or {}).values()]}
    _same_data(read)

    def row(name: str, path: str | Path) -> dict[str, Any]:
        report = read[str(path)]
        overall = report["overall"]
        bins = [{"name": b["name"], "miou": b["miou"], "miou_ci": b.get("miou_ci")}
                for b in report["bins"]]  # fmt: skip
        return {"name": name, "miou": overall["miou"], "miou_ci": overall.get("miou_ci"),
                "num_images": overall["num_images"], "bins": bins}  # fmt: skip

    points = [{"budget": float(b), **row(f"{100 * b:g} %", p)} for b, p in sorted(reports.items())]
    lines = [row(name, path) for name, path in (references or {}).items()]
    return points, lines


def plot_budget_curve(
    points: list[dict[str, Any]],
    path: str | Path,
    references: list[dict[str, Any]] | None = None,
    bins: bool = False,
) -> Path:
    """mIoU against the budget (log axis, in %), interval bars; references as bands."""
    panels = 2 if bins else 1
    fig = Figure(figsize=(7, 4.2 * panels), layout="constrained")
    axes = fig.subplots(panels, 1, squeeze=False)[:, 0]
    xs = [100 * p["budget"] for p in points]
    values = [math.nan if p["miou"] is None else p["miou"] for p in points]
    ax = axes[0]
    ax.errorbar(xs, values, yerr=error_bars(values, points, "miou_ci"), fmt="o-", color="k",
                capsize=4, label="fine-tuned on the budget")  # fmt: skip
    for k, ref in enumerate(references or []):
        colour = f"C{k}"
        if ref["miou"] is not None:
            ax.axhline(ref["miou"], color=colour, ls="--", lw=1, label=ref["name"])
        if ref.get("miou_ci"):
            ax.axhspan(*ref["miou_ci"], color=colour, alpha=0.15, lw=0)
    ax.set_title("mIoU against the label budget (bars: bootstrap intervals)")
    if bins and points:
        names = [b["name"] for b in points[-1]["bins"]]
        for k, name in enumerate(names):
            empty: dict[str, Any] = {}
            rows = [next((b for b in p["bins"] if b["name"] == name), empty) for p in points]
            ys = [math.nan if r.get("miou") is None else r["miou"] for r in rows]
            shift = np.array(xs) * (1 + 0.04 * (k - (len(names) - 1) / 2))  # apart on a log axis
            axes[1].errorbar(shift, ys, yerr=error_bars(ys, rows, "miou_ci"), fmt="o-",
                             capsize=3, color=f"C{k}", label=name)  # fmt: skip
        axes[1].set_title("per complexity bin")
    for axis in axes:
        axis.set_xscale("log")
        axis.set_xticks(xs, [f"{x:.3g}" for x in xs])
        axis.minorticks_off()
        axis.set(xlabel="labelled training images (%)", ylabel="mIoU", ylim=(0, 1.05))
        axis.grid(alpha=0.3)
        if axis.get_legend_handles_labels()[0]:
            axis.legend(fontsize=8)
    return save_figure(fig, path)


def budget_markdown(points: list[dict[str, Any]], references: list[dict[str, Any]]) -> str:
    """The curve as a Markdown table: budget (or reference), images scored, mIoU [interval]."""
    rows = [[p["name"], str(p["num_images"]), with_ci(p["miou"], p["miou_ci"])] for p in points]
    rows += [[r["name"], str(r["num_images"]), with_ci(r["miou"], r["miou_ci"])]
             for r in references]  # fmt: skip
    return "\n".join(md_table(["budget", "images", "mIoU [interval]"], rows)) + "\n"


def budget_curve(
    reports: Mapping[float, str | Path],
    output: str | Path,
    references: Mapping[str, str | Path] | None = None,
    bins: bool = False,
) -> list[dict[str, Any]]:
    """Read the reports, draw the curve as ``output`` (a PNG) and return its points.

    Raises:
        UsageError: see :func:`budget_rows`.
    """
    points, lines = budget_rows(reports, references)
    plot_budget_curve(points, output, lines, bins=bins)
    return points

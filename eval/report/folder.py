"""Writing a report folder: the JSON, the confusions, the plots and ``report.md``.

``report.json`` is written last: its presence marks the folder as this tool's, complete.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.cli import atomic_write_text
from claravid.eval.analysis.table import EvalResult
from claravid.eval.report.files import CONFUSIONS, REPORT, save_confusions, write_json
from claravid.eval.report.markdown import metric_markdown, report_markdown
from claravid.eval.report.plots import (
    PLOTS,
    plot_bins,
    plot_hardest,
    plot_heatmap,
    plot_metric_bins,
    plot_metric_scatter,
    plot_scatter,
    plot_tiles,
)


def write_outputs(
    out: str | Path,
    report: dict[str, Any],
    result: EvalResult,
    hardest: Sequence[dict[str, Any]] = (),
    colors: np.ndarray | None = None,
) -> dict[str, Path]:
    """Write the report folder: ``report.json``, ``confusions.npz``, plots, ``report.md``.

    ``report.json`` is written last: it marks the folder as this tool's, complete.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = {"confusions": save_confusions(out / CONFUSIONS, result)}
    plots: dict[str, str] = {}
    if report["bins"]:
        written["bins"] = plot_bins(report, out / PLOTS["bins"])
        written["heatmap"] = plot_heatmap(report, out / PLOTS["heatmap"])
    if "delent" in report["correlation"]:
        written["scatter"] = plot_scatter(report, out / PLOTS["scatter"])
    if hardest and colors is not None:
        written["hardest"] = plot_hardest(hardest, colors, out / PLOTS["hardest"], result.classes)
    tiled = [item for item in hardest if "tiles" in item]
    if tiled:
        written["tiles"] = plot_tiles(tiled, out / PLOTS["tiles"])
    for name in ("bins", "scatter", "heatmap", "hardest", "tiles"):
        if name in written:
            plots[name] = PLOTS[name]
        else:  # a plot of an earlier report in this folder would no longer match it
            (out / PLOTS[name]).unlink(missing_ok=True)
    written["markdown"] = atomic_write_text(out / "report.md", report_markdown(report, plots))
    written["report"] = write_json(out / REPORT, report)
    return written


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "metric"


def write_metric_outputs(out: str | Path, report: dict[str, Any]) -> str:
    """Write a ``--scores`` report folder: per metric its bins and scatter plots, ``report.md``
    and ``report.json`` (last: it marks the folder complete). Returns the Markdown text."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plots = {}
    for name in report["metrics"]:
        slug = _slug(name)
        if report["bins"]:
            plots[f"{name} per bin"] = plot_metric_bins(report, name, out / f"{slug}_per_bin.png")
        if "delent" in report["correlation"]:
            file = out / f"{slug}_vs_delent.png"
            plots[f"{name} vs delent"] = plot_metric_scatter(report, name, file)
    text = metric_markdown(report, {k: Path(v).name for k, v in plots.items()})
    atomic_write_text(out / "report.md", text)
    write_json(out / REPORT, report)
    return text

"""Writing a report folder: the JSON, the confusions, the plots and ``report.md``.

A folder is replaced whole or not at all (:func:`staged_folder`): written aside, then renamed
into place. ``report.json`` and ``confusions.npz`` carry one random ``report_id``, so a reader
knows the two belong together.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.dsp.measures import METRICS
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
from claravid.eval.report.quality_plots import QUALITY_PLOTS, plot_consistency, plot_reliability
from claravid.infra.files import atomic_write_text, current_umask

#: The per-image table as CSV: path, mIoU, pixel accuracy and the measures beyond mIoU, the
#: columns ``claravid-eval scores`` correlates with scene complexity.
IMAGES_CSV = "images.csv"
#: Files every report folder of this tool may hold: replaced with the folder.
_OURS = frozenset(
    {REPORT, CONFUSIONS, "report.md", IMAGES_CSV, *PLOTS.values(), *QUALITY_PLOTS.values()}
)


def report_files(folder: str | Path) -> set[str]:
    """The names of the files the report in ``folder`` wrote: the fixed ones, and for a
    ``scores`` report ``<metric>_per_bin.png`` and ``<metric>_vs_delent.png`` of each metric
    its ``report.json`` lists. Anything else there (a user's ``baseline_per_bin.png``, notes, a
    predictions folder) is not the report's, and moves into the folder that replaces it."""
    names = set(_OURS)
    try:
        old = json.loads((Path(folder) / REPORT).read_text(encoding="utf-8"))
        metrics = old.get("metrics") if old["source"]["kind"] == "scores" else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return names  # no readable report.json: only the fixed names are known to be ours
    for name in metrics if isinstance(metrics, list) else []:
        names |= set(metric_plot_names(str(name)))
    return names


def metric_plot_names(metric: str) -> tuple[str, str]:
    """The two plot files of a ``scores`` metric: per bin, and against delentropy."""
    slug = _slug(metric)
    return f"{slug}_per_bin.png", f"{slug}_vs_delent.png"


@contextlib.contextmanager
def staged_folder(out: str | Path) -> Iterator[Path]:
    """Write a report folder aside, then put it in place whole.

    The new folder is written into a hidden sibling; once complete, the old folder is renamed
    aside and the new one into place (two renames: ``out`` never holds new files beside an old
    report), files of the old folder that its report did not write (:func:`report_files`) are
    moved over, and the old folder is removed. An interrupted write (Ctrl-C, a full disk)
    leaves ``out`` as it was.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.new-", dir=out.parent))
    try:
        yield staging
        staging.chmod(0o777 & ~current_umask())  # mkdtemp's 0700 is not a report folder's mode
        if not out.exists():
            os.replace(staging, out)
            return
        ours = report_files(out)  # read before the swap: what the old report wrote
        aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        old = aside / out.name
        os.replace(out, old)
        os.replace(staging, out)
        for entry in old.iterdir():
            if entry.name not in ours and not (out / entry.name).exists():
                os.replace(entry, out / entry.name)
        shutil.rmtree(aside, ignore_errors=True)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def write_outputs(
    out: str | Path,
    report: dict[str, Any],
    result: EvalResult,
    hardest: Sequence[dict[str, Any]] = (),
    colors: np.ndarray | None = None,
) -> dict[str, Path]:
    """Write the report folder: ``report.json``, ``confusions.npz``, plots, ``report.md``.

    The folder is written aside and put in place whole (:func:`staged_folder`); ``report`` gets
    a new ``source.report_id``, also stored in ``confusions.npz``.
    """
    report["source"]["report_id"] = uuid.uuid4().hex
    with staged_folder(out) as folder:
        written = _write_report(folder, report, result, hardest, colors)
    return {name: Path(out) / path.name for name, path in written.items()}


def _write_report(
    out: Path,
    report: dict[str, Any],
    result: EvalResult,
    hardest: Sequence[dict[str, Any]],
    colors: np.ndarray | None,
) -> dict[str, Path]:
    written = {
        "confusions": save_confusions(out / CONFUSIONS, result, report["source"]["report_id"])
    }
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
    quality = report.get("quality") or {}
    computed = {n for n, e in quality.items() if e.get("status") == "computed"}
    if "calibration" in computed:
        written["reliability"] = plot_reliability(report, out / QUALITY_PLOTS["reliability"])
    if "consistency" in computed and report["bins"]:
        written["consistency"] = plot_consistency(report, out / QUALITY_PLOTS["consistency"])
    names = {**PLOTS, **QUALITY_PLOTS}
    order = ("bins", "scatter", "heatmap", "hardest", "tiles", "reliability", "consistency")
    plots = {name: names[name] for name in order if name in written}
    written["images"] = atomic_write_text(out / IMAGES_CSV, images_csv(report))
    written["markdown"] = atomic_write_text(out / "report.md", report_markdown(report, plots))
    written["report"] = write_json(out / REPORT, report)
    return written


def images_csv(report: dict[str, Any]) -> str:
    """``images.csv``: one row per image, its path and every per-image score of the report
    (mIoU, pixel accuracy, mBoundaryIoU, ECE, consistency of its pair; not the complexity,
    which ``scores`` measures itself); an empty cell where an image has no value (no pair,
    no class present)."""
    rows = report["images"]
    skip = {"path", *METRICS}
    columns = list(dict.fromkeys(k for row in rows for k in row if k not in skip))
    lines = [",".join(["path", *columns])]
    for row in rows:
        cells = [_csv_cell(row["path"])]
        cells += ["" if row.get(c) is None else repr(float(row[c])) for c in columns]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def _csv_cell(text: str) -> str:
    """A CSV cell, quoted when it holds a comma, a quote or a line break."""
    if any(c in text for c in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "metric"


def write_metric_outputs(out: str | Path, report: dict[str, Any]) -> str:
    """Write a ``scores`` report folder: per metric its bins and scatter plots, ``report.md``
    and ``report.json`` (last: it marks the folder complete). Returns the Markdown text."""
    with staged_folder(out) as folder:
        plots = {}
        for name in report["metrics"]:
            per_bin, scatter = metric_plot_names(name)  # what report_files reads back
            if report["bins"]:
                plots[f"{name} per bin"] = plot_metric_bins(report, name, folder / per_bin)
            if "delent" in report["correlation"]:
                plots[f"{name} vs delent"] = plot_metric_scatter(report, name, folder / scatter)
        text = metric_markdown(report, {k: Path(v).name for k, v in plots.items()})
        atomic_write_text(folder / "report.md", text)
        write_json(folder / REPORT, report)
    return text

"""``claravid-eval --compare A/report.json B/report.json ...``: bin tables side by side.

Typical use: a ClaraVid-trained and a UAVid-trained model evaluated on UAVid val with the same
fixed ``--edges``; the table and the plot show the synthetic-to-real gap per complexity bin.
Reports binned differently (other edges, quantile bins of different data) or on different
palettes are still shown, with a warning: their rows do not cover the same images.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from claravid.eval.markdown import compare_markdown
from claravid.eval.plots import plot_compare
from claravid.eval.report import read_report


def _edges(report: dict[str, Any]) -> list[tuple[Any, Any]]:
    return [(b.get("lo"), b.get("hi")) for b in report["bins"]]


def comparison_warnings(reports: Sequence[dict[str, Any]], names: Sequence[str]) -> list[str]:
    """What makes the side-by-side rows not comparable: palettes, binning, bin ranges."""
    out = []
    first, name0 = reports[0], names[0]
    for report, name in itertools.islice(zip(reports, names, strict=True), 1, None):
        if report["palette"] != first["palette"] or report["classes"] != first["classes"]:
            out.append(
                f"palettes differ: {name0} uses {first['palette']}, {name} uses "
                f"{report['palette']}; mIoUs average different classes"
            )
        b0 = first["source"].get("binning", {})
        b1 = report["source"].get("binning", {})
        if b0.get("method") != b1.get("method") or b0.get("edges") != b1.get("edges"):
            out.append(
                f"bin edges differ: {name0} {b0.get('method')} {b0.get('edges') or ''} vs "
                f"{name} {b1.get('method')} {b1.get('edges') or ''}; evaluate both with the same "
                "--edges to compare bin by bin"
            )
        elif b0.get("method") != "fixed" and _edges(first) != _edges(report):
            out.append(
                f"bin edges differ: quantile bins of {name0} and {name} cover different "
                "delentropy ranges; use the same --edges to compare bin by bin"
            )
    return out


def compare_reports(
    paths: Sequence[str | Path], output: str | Path | None = None
) -> tuple[str, list[str]]:
    """The comparison as Markdown and its warnings; with ``output``, also ``compare.md`` and
    ``compare.png`` there.

    Raises:
        UsageError: a file is not a claravid-eval report.
    """
    reports = [read_report(Path(p) / "report.json" if Path(p).is_dir() else p) for p in paths]
    names = _names(paths)
    warnings = comparison_warnings(reports, names)
    text = compare_markdown(reports, names, warnings)
    if output is not None:
        from claravid.cli import atomic_write_text

        out = Path(output)
        out.mkdir(parents=True, exist_ok=True)
        plot_compare(reports, names, out / "compare.png")
        atomic_write_text(out / "compare.md", text + "\n![compare](compare.png)\n")
    return text, warnings


def _names(paths: Sequence[str | Path]) -> list[str]:
    """Short, distinct names: the report's folder name (parent folders added on clashes)."""
    folders = [Path(p) if Path(p).is_dir() else Path(p).parent for p in paths]
    names = [f.resolve().name or str(f) for f in folders]
    if len(set(names)) < len(names):
        names = [str(f) for f in folders]
    return names

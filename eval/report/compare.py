"""``claravid-eval compare A B ...``: bin tables side by side, and the gaps with intervals.

Typical use: a ClaraVid-trained and a UAVid-trained model evaluated on UAVid val with the same
fixed ``--edges``; the table and the plot show the synthetic-to-real gap per complexity bin.
Reports binned differently (other edges, quantile bins of different data) or on different
palettes are still shown, with a warning: their rows do not cover the same images. The gaps
themselves (paired or unpaired, with intervals and p-values) are
:func:`claravid.eval.analysis.gaps.gap_analysis`; this module reads the reports and writes
``compare.md``, ``compare.png`` and ``compare.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.gaps import cluster_unit, comparison_warnings, gap_analysis
from claravid.eval.report.files import CONFUSIONS, load_result, read_report, write_json
from claravid.eval.report.markdown import compare_markdown
from claravid.eval.report.plots import plot_compare
from claravid.infra.files import atomic_write_text


def _folder(path: str | Path) -> Path:
    path = Path(path)
    return path if path.is_dir() else path.parent


def compare_reports(
    paths: Sequence[str | Path],
    output: str | Path | None = None,
    settings: Bootstrap | None = None,
    cluster: str | None = None,
) -> tuple[str, list[str]]:
    """The comparison as Markdown and its warnings; with ``output``, also ``compare.md``,
    ``compare.png`` and (when every report has its confusions) ``compare.json`` there.

    Args:
        paths: report folders or their ``report.json``; the first is the baseline.
        output: the folder to write to (None: only return the text).
        settings: bootstrap settings of the gaps (default 1000 resamples, 0.95, seed 0);
            ``resamples=0`` still gives the gaps, without intervals.
        cluster: the cluster unit (default: the baseline's dataset default).

    Raises:
        UsageError: a file is not a claravid-eval report, or the cluster unit is missing.
    """
    reports = [read_report(Path(p) / "report.json" if Path(p).is_dir() else p) for p in paths]
    names = _names(paths)
    warnings = comparison_warnings(reports, names)
    analysis = None
    missing = [str(p) for p in paths if not (_folder(p) / CONFUSIONS).is_file()]
    if len(paths) >= 2 and not missing:
        results = [load_result(p) for p in paths]
        base = settings or Bootstrap()
        unit = cluster_unit(results, names, cluster)
        analysis = gap_analysis(
            results,
            reports,
            names,
            Bootstrap(resamples=base.resamples, level=base.level, seed=base.seed, cluster=unit),
        )
    note = None
    if missing and len(paths) >= 2:
        note = (
            f"no {CONFUSIONS} beside {', '.join(missing)}: gaps are shown without intervals "
            "or p-values"
        )
    text = compare_markdown(reports, names, warnings, analysis, note)
    if output is not None:
        out = Path(output)
        out.mkdir(parents=True, exist_ok=True)
        plot_compare(reports, names, out / "compare.png", analysis)
        if analysis is not None:
            write_json(out / "compare.json", analysis)
        else:
            (out / "compare.json").unlink(missing_ok=True)
        atomic_write_text(out / "compare.md", text + "\n![compare](compare.png)\n")
    return text, warnings


def _names(paths: Sequence[str | Path]) -> list[str]:
    """Short, distinct names: the report's folder name (parent folders added on clashes)."""
    folders = [Path(p) if Path(p).is_dir() else Path(p).parent for p in paths]
    names = [f.resolve().name or str(f) for f in folders]
    if len(set(names)) < len(names):
        names = [str(f) for f in folders]
    return names

"""``claravid-eval --compare A/report.json B/report.json ...``: bin tables side by side.

Typical use: a ClaraVid-trained and a UAVid-trained model evaluated on UAVid val with the same
fixed ``--edges``; the table and the plot show the synthetic-to-real gap per complexity bin.
Reports binned differently (other edges, quantile bins of different data) or on different
palettes are still shown, with a warning: their rows do not cover the same images.

With ``confusions.npz`` beside every report, each report B after the first (the baseline A)
also gets its mIoU gap B − A, overall and per bin (matched by position), with a cluster
bootstrap interval and a two-sided p-value (``compare.json``). *Paired* when A and B cover the
same images (same paths): the same clusters are resampled for both and the gap is taken per
resample, which removes the spread between images. *Unpaired* otherwise: each report resamples
its own clusters independently (a wider interval), and the comparison says so.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.cli import UsageError
from claravid.eval.bins import Bin, fixed_bins, quantile_bins
from claravid.eval.bootstrap import Bootstrap, paired_gap, unpaired_gap
from claravid.eval.markdown import compare_markdown
from claravid.eval.plots import plot_compare
from claravid.eval.report import CONFUSIONS, EvalResult, load_result, read_report


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


def report_bins(result: EvalResult, report: dict[str, Any]) -> list[Bin]:
    """The bins of a report, re-derived from its per-image table and its recorded binning."""
    binning = report["source"].get("binning", {})
    values = result.complexity.get(binning.get("measure", ""))
    if values is None or not binning.get("method"):
        return []
    if binning["method"] == "fixed":
        return fixed_bins(values, binning["edges"])[0]
    return quantile_bins(values, result.paths, int(binning["bins"]))


def _cluster(results: Sequence[EvalResult], names: Sequence[str], wanted: str | None) -> str:
    """The cluster unit every report carries: ``wanted``, else the baseline's default."""
    unit = wanted or results[0].default_cluster()
    for result, name in zip(results, names, strict=True):
        if unit not in result.units():
            raise UsageError(
                f"--cluster {unit} is not available for {name} (it has: "
                f"{', '.join(result.units())}); pick a unit every report has"
            )
    return unit


def gap_analysis(
    results: Sequence[EvalResult],
    reports: Sequence[dict[str, Any]],
    names: Sequence[str],
    settings: Bootstrap,
) -> dict[str, Any]:
    """``compare.json``: the mIoU gap of each report against the first, with intervals.

    Args:
        results: per-image tables (:func:`claravid.eval.report.load_result`), baseline first.
        reports: their ``report.json`` (for the binning and the bin names).
        names: how each report is named in the output.
        settings: resamples, level, seed and the cluster unit.
    """
    base, base_report = results[0], reports[0]
    base_ids = _ids(base, settings.cluster)
    base_bins = report_bins(base, base_report)
    comparisons = []
    for j, (result, report, name) in enumerate(
        zip(results[1:], reports[1:], names[1:], strict=True), 1
    ):
        pair = _Pair(base, result, base_ids, settings)
        other_bins = report_bins(result, report)
        entry: dict[str, Any] = {
            "report": name,
            "paired": pair.paired,
            "overall": pair.gap(
                range(len(base.paths)), range(len(result.paths)), f"compare:{j}:overall"
            ),
            "bins": [],
        }
        for a, b in zip(base_bins, other_bins, strict=False):
            row = pair.gap(a.indices, b.indices, f"compare:{j}:bin:{a.name}")
            entry["bins"].append({"name": a.name, **row})
        if not pair.paired:
            entry["note"] = (
                f"{name} and {names[0]} cover different images: unpaired comparison, each "
                "resampled independently"
            )
        comparisons.append(entry)
    return {
        "baseline": names[0],
        "comparisons": comparisons,
        "uncertainty": settings.describe(int(base_ids.max()) + 1 if base_ids.size else 0),
    }


class _Pair:
    """Baseline A and report B: paired (same images) or not, and the gap of two image sets."""

    def __init__(self, a: EvalResult, b: EvalResult, a_ids: np.ndarray, settings: Bootstrap):
        self.a, self.b, self.a_ids, self.settings = a, b, a_ids, settings
        self.paired = sorted(b.paths) == sorted(a.paths) and b.classes == a.classes
        if self.paired:
            # B's rows in A's image order; both resample A's clusters.
            where = {p: i for i, p in enumerate(b.paths)}
            order = np.asarray([where[p] for p in a.paths], dtype=np.int64)
            self.b_conf = b.confusions[order]
            self.b_to_a = np.argsort(order)
        else:
            self.b_ids = _ids(b, settings.cluster)

    def gap(self, members_a: Sequence[int], members_b: Sequence[int], stream: str) -> dict:
        """The gap B − A of A's ``members_a`` and B's ``members_b``; paired when the two
        reports cover the same images and the two sets are the same images."""
        if self.paired and sorted(members_a) == sorted(int(self.b_to_a[i]) for i in members_b):
            out = paired_gap(self.a.confusions, self.b_conf, self.a_ids, members_a,
                             self.settings, stream=stream)  # fmt: skip
            return {"paired": True, **out}
        b_ids = _ids(self.b, self.settings.cluster) if self.paired else self.b_ids
        out = unpaired_gap(self.a.confusions, self.a_ids, members_a, self.b.confusions, b_ids,
                           members_b, self.settings, stream=stream)  # fmt: skip
        return {"paired": False, **out}


def _ids(result: EvalResult, unit: str) -> np.ndarray:
    from claravid.eval.bootstrap import cluster_ids

    return cluster_ids(result.cluster_labels(unit))


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
        unit = _cluster(results, names, cluster)
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
        from claravid.cli import atomic_write_text
        from claravid.eval.report import write_json

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

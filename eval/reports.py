"""Runs over saved report folders, no model and no torch: merge (or re-bin) and compare.

::

    from claravid.eval import ReportSettings, compare, merge

    merge(["part0", "part1"], "all", ReportSettings(edges=[4, 4.5, 5]))
    print(compare(["all", "other"], "cmp"))

What a user should know (different runs merged, tiles dropped, images outside fixed edges,
reports that are not comparable bin by bin) is a :class:`UserWarning`.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.table import EvalResult
from claravid.eval.report.files import REPORT, check_report_kind
from claravid.eval.settings import Evaluation, ReportSettings, check_type
from claravid.infra.cli import UsageError
from claravid.infra.files import check_output_dir


def warn_outside_edges(report: dict[str, Any], values: np.ndarray, total: int) -> None:
    """Say when fixed edges leave images in no bin (the report counts them only)."""
    outside = report["source"].get("binning", {}).get("outside") or []
    if outside:
        values = np.asarray(values, dtype=float)
        values = values[np.isfinite(values)]
        span = f"{values.min():.2f}..{values.max():.2f}" if values.size else "n/a"
        warnings.warn(
            f"{len(outside)} of {total} image(s) fall outside --edges (delentropy of the "
            f"images: {span}): they are in no bin",
            UserWarning,
            stacklevel=3,
        )


def merge(
    parts: Sequence[str | Path],
    output: str | Path,
    settings: ReportSettings | None = None,
    *,
    overwrite: bool = False,
) -> Evaluation:
    """Merge report folders (job-array parts) into one report, or re-bin one report.

    Raises:
        UsageError: the output is not this tool's folder (without ``overwrite``), a part is
            not a report, or more bins than images.
    """
    from claravid.eval.analysis.table import merge_results
    from claravid.eval.report.build import build_report
    from claravid.eval.report.files import load_result
    from claravid.eval.report.folder import write_outputs
    from claravid.eval.settings import check_classes

    parts = report_list(parts, "merge", "merge(['part0', 'part1'], 'all')")
    check_type(settings, ReportSettings, "settings", "ReportSettings(bins=5)")
    settings = settings or ReportSettings()
    output = Path(output)
    check_output_dir(output, marker=REPORT, overwrite=overwrite)
    check_report_kind(output, scores=False, overwrite=overwrite)
    results = [load_result(p) for p in parts]
    _warn_different_runs(results)
    result = merge_results(results, [str(p) for p in parts])
    _warn_dropped_tiles(results, result, parts)
    settings.check_bins(len(result.paths))
    check_classes(settings.classes, result.classes)
    report = build_report(
        result,
        bins=settings.bins,
        edges=settings.edges,
        group_by=settings.group_by,
        bootstrap=settings.intervals(result.attributes, result.default_cluster()),
        classes=settings.classes,
    )
    warn_outside_edges(report, result.complexity["delent"], len(result.paths))
    write_outputs(output, report, result)
    return Evaluation(output, report, result)


def report_list(paths: Any, verb: str, example: str) -> list[str | Path]:
    """The report folders of a merge or a comparison, as a list.

    Raises:
        TypeError: one path given where a list is expected (a string would be read letter by
            letter).
        ValueError: no report at all.
    """
    if isinstance(paths, (str, bytes, Path)):
        raise TypeError(
            f"{verb} takes a list of report folders, got the single path {str(paths)!r}: write "
            f"[{str(paths)!r}] (e.g. {example})"
        )
    paths = list(paths)
    if not paths:
        noun = "report folder to merge" if verb == "merge" else "report to compare"
        raise ValueError(f"{verb} needs at least one {noun} (e.g. {example})")
    return paths


def _warn_different_runs(parts: Sequence[EvalResult]) -> None:
    """Job-array parts share one model and one data selection; say when they do not. A model
    file or data root is known by the real path behind it: one root spelled two ways (``..``,
    a symlink, a trailing slash) is one root."""
    for key, what in (("path", "model"), ("split", "split"), ("data", "data root")):
        seen = {str(p.source.get(key)) for p in parts if p.source.get(key) is not None}
        if key == "split":  # split files are how job-array parts shard a split: fine
            seen &= {"train", "val", "test", "all"}
        else:
            seen = {os.path.realpath(s) for s in seen}
        if len(seen) > 1:
            warnings.warn(
                f"merging reports of different {what}s ({', '.join(sorted(seen))}): the merged "
                "numbers mix them",
                UserWarning,
                stacklevel=3,
            )


def _warn_dropped_tiles(
    parts: Sequence[EvalResult], merged: EvalResult, names: Sequence[str | Path]
) -> None:
    """Tiles merge only when every part has tiles of one size; say when some are dropped."""
    if merged.tiles is None and any(p.tiles is not None for p in parts):
        sizes = [f"{n}: {p.tiles.size if p.tiles is not None else 'none'}"
                 for p, n in zip(parts, names, strict=True)]  # fmt: skip
        warnings.warn(
            "the merged report has no tiles: the parts' tile sizes differ or some have none "
            f"({'; '.join(sizes)}); evaluate every part with the same --tiles",
            UserWarning,
            stacklevel=3,
        )


def compare(
    reports: Sequence[str | Path],
    output: str | Path | None = None,
    bootstrap: Bootstrap | None = None,
    cluster: str | None = None,
    *,
    oracle: str | Path | None = None,
    overwrite: bool = False,
) -> str:
    """Compare reports, the first the baseline: the Markdown table; with ``output`` also
    ``compare.md``, ``compare.png`` and ``compare.json`` there.

    Args:
        reports: report folders or their ``report.json``.
        output: the folder to write to (None: only return the text).
        bootstrap: resamples, level and seed of the gaps' intervals (default 1000, 0.95, 0).
        cluster: the resampled unit (default: the baseline's dataset default).
        oracle: a target-supervised model's report: the first report is then the source-only
            model, the others adapted ones, and the comparison adds the fraction of the
            source-to-oracle gap each closes, per bin and per class, with intervals.
        overwrite: replace a folder this tool did not write.
    """
    from claravid.eval.report.compare import compare_reports

    reports = report_list(reports, "compare", "compare(['a', 'b'], 'cmp')")
    # A comparison of one compares nothing (with an oracle, compare_reports says what it needs).
    if len(reports) < 2 and oracle is None:
        raise UsageError(
            f"compare needs two or more reports, the first the baseline; got only "
            f"{reports[0]}: add the report(s) to set beside it"
        )
    check_type(bootstrap, Bootstrap, "bootstrap", "Bootstrap(resamples=1000)")
    if output is not None:
        check_output_dir(output, marker="compare.md", overwrite=overwrite)
    text, messages = compare_reports(reports, output, bootstrap, cluster, oracle)
    for message in messages:
        warnings.warn(message, UserWarning, stacklevel=2)
    return text

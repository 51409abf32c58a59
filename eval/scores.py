"""``claravid-eval --scores FILE.csv``: the complexity analysis for any per-image metric.

The CSV holds a ``path`` column (relative to ``--data``, or absolute) and one or more numeric
columns: the PSNR/SSIM/LPIPS of a reconstruction's test views, a depth error, a detector's AP.
No model and no labels are needed. The report gives, per complexity bin and per group
(``--group-by``), the number of images and the mean of each metric with its cluster bootstrap
interval; per group also the DSP profile (μ, σ, α, β) of its delentropy, next to the metric
means (the layout of the ClaraVid paper's supplementary Table 5); and the Pearson and
Spearman correlations of every complexity measure with every metric, with intervals (Fig. 6).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.cli import UsageError, atomic_write_text, check_output_dir
from claravid.eval.bins import Bin, fixed_bins, quantile_bins
from claravid.eval.bootstrap import Bootstrap, cluster_ids, correlation_interval, mean_interval
from claravid.eval.complexity import PRIMARY_MEASURE
from claravid.eval.report import write_json
from claravid.eval.stratify import correlation, group_profile, order_warnings
from claravid.eval.units import unit_labels

PATH_COLUMN = "path"
REPORT = "report.json"
CONVENTION = (
    "Per-image metrics from the CSV; the mean of a group (bin, group, all) is the plain mean "
    "of its images' values; correlations are Pearson and Spearman (scipy) between per-image "
    "complexity and the per-image metric, with n; intervals resample clusters of dependent "
    "images (cluster percentile bootstrap)."
)
_SHOWN = 5  # rows named in an error


def _rows(numbers: Sequence[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:_SHOWN])
    more = f" and {len(numbers) - _SHOWN} more" if len(numbers) > _SHOWN else ""
    return f"row{'s' if len(numbers) > 1 else ''} {shown}{more}"


def read_scores(path: str | Path, root: str | Path) -> tuple[list[str], dict[str, np.ndarray]]:
    """Read a scores CSV.

    Rows are numbered as in a spreadsheet: the header is row 1.

    Args:
        path: the CSV file.
        root: the data root relative paths are taken from.

    Returns:
        ``(paths, metrics)``: absolute, normalised image paths in CSV order, and metric
        column -> float64 [N].

    Raises:
        UsageError: unreadable file, no ``path`` column, no metric column, an empty path,
            a non-numeric or non-finite value, or a path listed twice (the rows are named).
    """
    path, root = Path(path), Path(root).absolute()
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            header = [h.strip() for h in (reader.fieldnames or [])]
            records = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise UsageError(f"cannot read the scores CSV {path} ({exc})") from None
    if PATH_COLUMN not in header:
        raise UsageError(
            f"{path} has no '{PATH_COLUMN}' column (header: {', '.join(header) or 'none'}); "
            f"write a header like path,psnr,ssim"
        )
    raw_names = reader.fieldnames or []
    columns = [(raw, h) for raw, h in zip(raw_names, header, strict=True) if h != PATH_COLUMN]
    if not columns:
        raise UsageError(f"{path} has no metric column beside '{PATH_COLUMN}' (e.g. psnr)")
    if not records:
        raise UsageError(f"{path} lists no image")
    path_key = raw_names[header.index(PATH_COLUMN)]
    paths: list[str] = []
    metrics = {name: np.empty(len(records)) for _, name in columns}
    empty, bad, extra = [], [], []
    for i, record in enumerate(records):
        row = i + 2
        if None in record:  # more cells than header columns
            extra.append(row)
        text = (record.get(path_key) or "").strip()
        if not text:
            empty.append(row)
        file = Path(text).expanduser()
        paths.append(str(Path(_normal(file if file.is_absolute() else root / file))))
        for raw, name in columns:
            cell = (record.get(raw) or "").strip()
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                bad.append(f"row {row} {name}={cell!r}")
            metrics[name][i] = value
    if extra:
        raise UsageError(f"{path}: more cells than header columns in {_rows(extra)}")
    if empty:
        raise UsageError(f"{path}: empty '{PATH_COLUMN}' in {_rows(empty)}")
    if bad:
        more = f" and {len(bad) - _SHOWN} more" if len(bad) > _SHOWN else ""
        raise UsageError(
            f"{path}: values that are not finite numbers: {', '.join(bad[:_SHOWN])}{more}"
        )
    seen: dict[str, int] = {}
    duplicates = []
    for i, p in enumerate(paths):
        if p in seen:
            duplicates.append(f"row {i + 2} repeats row {seen[p] + 2}")
        seen.setdefault(p, i)
    if duplicates:
        raise UsageError(
            f"{path}: duplicate paths: {', '.join(duplicates[:_SHOWN])}; give each image once"
        )
    return paths, metrics


def _normal(path: Path) -> str:
    """One spelling per file: absolute, ``..`` and ``.`` resolved, symlinks kept."""
    return os.path.normpath(str(path))


def match_images(csv_paths: Sequence[str], data_paths: Sequence[str], csv_file: Path) -> list[int]:
    """The data index of each CSV image.

    Raises:
        UsageError: CSV images that are not in the data (selected split), rows named.
    """
    index = {_normal(Path(p).absolute()): i for i, p in enumerate(data_paths)}
    missing = [i for i, p in enumerate(csv_paths) if p not in index]
    if missing:
        shown = ", ".join(f"row {i + 2} {csv_paths[i]}" for i in missing[:3])
        raise UsageError(
            f"{csv_file}: {len(missing)} image(s) are not in the data (root, --dataset, "
            f"--split): {_rows([i + 2 for i in missing])}, e.g. {shown}"
        )
    return [index[p] for p in csv_paths]


def _metric_row(
    members: Sequence[int],
    metrics: Mapping[str, np.ndarray],
    ids: np.ndarray,
    settings: Bootstrap,
    stream: str,
) -> dict[str, Any]:
    out = {}
    for name, values in metrics.items():
        m = mean_interval(values, ids, members, settings, stream=f"{stream}:{name}")
        out[name] = {"mean": m["mean"], "ci": m["ci"]}
        if m["ci_note"]:
            out[name]["ci_note"] = m["ci_note"]
    return out


def score_report(
    paths: Sequence[str],
    metrics: Mapping[str, np.ndarray],
    complexity: Mapping[str, np.ndarray],
    clusters: Sequence[str],
    settings: Bootstrap,
    *,
    bins: int = 3,
    edges: Sequence[float] | None = None,
    groups: Mapping[str, Sequence[int]] | None = None,
) -> dict[str, Any]:
    """The numbers of a ``--scores`` report (without ``source``).

    Returns:
        ``{"overall", "bins", "groups", "images", "correlation", "metrics", "convention",
        "binning", "uncertainty"}``: ``bins[i].scores`` = ``{metric: {"mean", "ci"}}``,
        ``correlation[measure][metric]`` = ``{"pearson", "spearman", "n", "pearson_ci",
        "spearman_ci"}``.
    """
    n = len(paths)
    ids = cluster_ids(clusters)
    measure = PRIMARY_MEASURE if PRIMARY_MEASURE in complexity else next(iter(complexity), None)
    values = complexity.get(measure) if measure else None
    report: dict[str, Any] = {
        "overall": {"num_images": n,
                    "scores": _metric_row(range(n), metrics, ids, settings, "overall")},
    }  # fmt: skip
    bin_list: list[Bin] = []
    if values is not None:
        if edges is not None:
            bin_list, outside = fixed_bins(values, edges)
            binning = {"measure": measure, "method": "fixed", "edges": [float(e) for e in edges]}
        else:
            bin_list, outside = quantile_bins(values, paths, bins), []
            binning = {"measure": measure, "method": "quantile", "bins": bins}
        binning["outside"] = [paths[i] for i in outside]
        report["binning"] = binning
    report["bins"] = []
    for b in bin_list:
        row: dict[str, Any] = {"name": b.name, "num_images": len(b.indices)}
        vals = values[list(b.indices)] if values is not None else np.zeros(0)
        row["lo"] = b.lo if edges is not None else (float(vals.min()) if len(vals) else None)
        row["hi"] = b.hi if edges is not None else (float(vals.max()) if len(vals) else None)
        row["scores"] = _metric_row(b.indices, metrics, ids, settings, f"bin:{b.name}")
        report["bins"].append(row)
    report["groups"] = []
    for name, members in (groups or {}).items():
        row = {"name": name, "num_images": len(members)}
        if values is not None and len(members):
            row["profile"] = group_profile(values[list(members)])
        row["scores"] = _metric_row(members, metrics, ids, settings, f"group:{name}")
        report["groups"].append(row)
    report["images"] = [
        {"path": p, **{m: float(v[i]) for m, v in complexity.items()},
         **{m: float(v[i]) for m, v in metrics.items()}}
        for i, p in enumerate(paths)
    ]  # fmt: skip
    report["correlation"] = {}
    for m, x in complexity.items():
        report["correlation"][m] = {}
        for name, y in metrics.items():
            entry = correlation(x, y)
            ci = correlation_interval(x, y, ids, settings, stream=f"correlation:{m}:{name}")
            entry.update({"pearson_ci": ci["pearson_ci"], "spearman_ci": ci["spearman_ci"]})
            if ci["ci_note"] and settings.enabled:
                entry["ci_note"] = ci["ci_note"]
            report["correlation"][m][name] = entry
    report["metrics"] = list(metrics)
    report["convention"] = CONVENTION
    uncertainty = settings.describe(int(ids.max()) + 1 if ids.size else 0)
    uncertainty["warnings"] = []
    for name in metrics:
        rows = [{"name": r["name"], **r["scores"][name]} for r in report["bins"]]
        for message in order_warnings(rows, "ci", "mean"):
            uncertainty["warnings"].append(f"{name}: {message}")
    report["uncertainty"] = uncertainty
    return report


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "metric"


def run_scores(args: argparse.Namespace) -> int:
    """The ``--scores`` mode of ``claravid-eval`` (arguments checked by the CLI)."""
    from claravid.eval.cli import data_bootstrap, selection_flags
    from claravid.eval.complexity import ComplexityJob
    from claravid.eval.data import open_data
    from claravid.eval.markdown import scores_markdown
    from claravid.eval.plots import plot_metric_bins, plot_metric_scatter

    if args.data is None:
        raise UsageError("--scores needs --data: the dataset root the CSV's paths belong to")
    check_output_dir(args.output, marker=REPORT, overwrite=args.overwrite)
    dataset = args.dataset or "claravid"
    csv_paths, metrics = read_scores(args.scores, args.data)
    data = open_data(
        args.data,
        dataset=dataset,
        split=args.split or ("all" if dataset == "claravid" else "val"),
        palette=args.palette,
        masks=args.masks,
        selection=selection_flags(args, dataset),
        labels=False,
    )
    if args.group_by is not None:
        data.groups(args.group_by)
    settings = data_bootstrap(args, data)
    order = match_images(csv_paths, data.paths, args.scores)
    paths = [data.paths[i] for i in order]
    if args.edges is None and (args.bins or 3) > len(paths):
        raise UsageError(f"{args.bins or 3} bins for {len(paths)} images: use --bins {len(paths)}")
    attributes = {a: [v[i] for i in order] for a, v in data.attributes.items()}
    clusters = unit_labels(paths, attributes, settings.cluster)
    groups = None
    if args.group_by is not None:
        groups = {}
        for pos, label in enumerate(attributes[args.group_by]):
            groups.setdefault(label, []).append(pos)
        groups = dict(sorted(groups.items()))
    values = ComplexityJob(paths, args.measures, threads=max(1, args.workers)).result()
    complexity = {m: np.asarray(values[m], dtype=np.float64) for m in args.measures}
    report = score_report(paths, metrics, complexity, clusters, settings,
                          bins=args.bins or 3, edges=args.edges, groups=groups)  # fmt: skip
    binning = {**report.pop("binning", {}), "group_by": args.group_by}
    report["source"] = {"kind": "scores", "scores": str(args.scores), **data.describe,
                        "measures": list(args.measures), "binning": binning}  # fmt: skip
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    plots = {}
    for name in metrics:
        slug = _slug(name)
        if report["bins"]:
            plots[f"{name} per bin"] = plot_metric_bins(report, name, out / f"{slug}_per_bin.png")
        if "delent" in complexity:
            file = out / f"{slug}_vs_delent.png"
            plots[f"{name} vs delent"] = plot_metric_scatter(report, name, file)
    text = scores_markdown(report, {k: Path(v).name for k, v in plots.items()})
    atomic_write_text(out / "report.md", text)
    write_json(out / REPORT, report)  # last: marks the folder complete
    print(text.split("## Correlations")[0].rstrip())
    for message in report["uncertainty"]["warnings"]:
        print(f"claravid-eval: warning: {message}", file=sys.stderr)
    print(f"\nreport: {out / 'report.md'} ({out / REPORT} and plots beside)")
    return 0

"""Complexity analysis of any per-image metric (``claravid-eval scores FILE.csv``).

Per-image values of a metric (the PSNR/SSIM/LPIPS of a reconstruction's test views, a depth
error, a detector's AP) need no model and no labels. The report gives, per complexity bin and
per group, the number of images and the mean of each metric with its cluster bootstrap
interval; per group also the DSP profile (μ, σ, α, β) of its delentropy, next to the metric
means (the layout of the ClaraVid paper's supplementary Table 5); and the Pearson and Spearman
correlations of every complexity measure with every metric, with intervals (its Fig. 6).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from claravid.eval.analysis.bins import Bin, choose_bins
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    correlation_interval,
    count_clusters,
    mean_interval,
)
from claravid.eval.analysis.complexity_measures import PRIMARY_MEASURE
from claravid.eval.analysis.metrics import finite_or_none
from claravid.eval.analysis.stats import correlation, group_profile, order_warnings

CONVENTION = (
    "Per-image metrics from the CSV; the mean of a group (bin, group, all) is the plain mean "
    "of its images' values; correlations are Pearson and Spearman (scipy) between per-image "
    "complexity and the per-image metric, with n; intervals resample clusters of dependent "
    "images (cluster percentile bootstrap)."
)


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


def metric_report(
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
    """The numbers of a ``scores`` report (without ``source``).

    Returns:
        ``{"overall", "bins", "groups", "images", "correlation", "metrics", "convention",
        "binning", "uncertainty"}``: ``bins[i].scores`` = ``{metric: {"mean", "ci"}}``,
        ``correlation[measure][metric]`` = ``{"pearson", "spearman", "n", "pearson_ci",
        "spearman_ci"}``.
    """
    n = len(paths)
    settings.check_memory(clusters)  # before anything is computed or allocated
    ids = cluster_ids(clusters)
    measure = PRIMARY_MEASURE if PRIMARY_MEASURE in complexity else next(iter(complexity), None)
    values = complexity.get(measure) if measure else None
    report: dict[str, Any] = {
        "overall": {"num_images": n,
                    "scores": _metric_row(range(n), metrics, ids, settings, "overall")},
    }  # fmt: skip
    bin_list: list[Bin] = []
    if measure is not None and values is not None:
        bin_list, outside, binning = choose_bins(values, paths, measure, bins=bins, edges=edges)
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
        {"path": p, **{m: finite_or_none(float(v[i])) for m, v in complexity.items()},
         **{m: finite_or_none(float(v[i])) for m, v in metrics.items()}}
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
    uncertainty = settings.describe(count_clusters(ids))
    uncertainty["warnings"] = []
    for name in metrics:
        rows = [{"name": r["name"], **r["scores"][name]} for r in report["bins"]]
        for message in order_warnings(rows, "ci", "mean"):
            uncertainty["warnings"].append(f"{name}: {message}")
    report["uncertainty"] = uncertainty
    return report

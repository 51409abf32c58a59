"""The mIoU gap of reports against a baseline, with cluster bootstrap intervals.

Each report B after the first (the baseline A) gets its mIoU gap B − A, overall and per bin
(matched by position), with a cluster bootstrap interval and a two-sided p-value. *Paired* when
A and B cover the same images (same paths): the same clusters are resampled for both and the gap
is taken per resample, which removes the spread between images. *Unpaired* otherwise: each
report resamples its own clusters independently (a wider interval), and the comparison says so.

*Not comparable* (no gap, interval or p-value computed, and the reason given): reports of
different class sets (palettes), whose mIoUs average different classes; and one run seen twice,
a report against its own re-binning or merge (or a copy of it): reports that share a
``report_id`` in their lineage (:attr:`~claravid.eval.analysis.table.EvalResult.lineage`), whose
gap is 0 by construction and any "significance" an artefact of the binning. Two *runs* that
agree everywhere (a checkpoint and its ONNX export, two seeds that converged alike) are a fair
comparison: a paired gap of 0, interval [0, 0], p = 1.

The measures beyond mIoU (mBoundaryIoU; ECE and MCE; cross-view consistency and TC) get their
gaps the same way, per bin, each from its own per-image sums
(:mod:`claravid.eval.analysis.sum_intervals`), under ``quality``; a measure that one of the
two reports lacks (switched off, no scores, a report written before it existed) is compared
nowhere and named under ``missing``.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from claravid.eval.analysis.bins import Bin, choose_bins
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    confusion_features,
    count_clusters,
    paired_gap,
    unpaired_gap,
)
from claravid.eval.analysis.predictable import subset_statistic
from claravid.eval.analysis.quality import STATISTICS, measure_rows
from claravid.eval.analysis.quality_table import COMPUTED, QUALITY, QualityTable
from claravid.eval.analysis.sum_intervals import paired_sums_gap, unpaired_sums_gap
from claravid.eval.analysis.table import EvalResult
from claravid.infra.cli import UsageError

#: The statistics of each measure beyond mIoU that comparisons give gaps of (the ground truth's
#: own consistency is the same for two models on the same images: not compared).
COMPARED: dict[str, tuple[str, ...]] = {
    "boundary_iou": ("miou",),
    "calibration": ("ece", "mce"),
    "consistency": ("agreement", "tc"),
}


def _edges(report: dict[str, Any]) -> list[tuple[Any, Any]]:
    return [(b.get("lo"), b.get("hi")) for b in report["bins"]]


def evaluation_protocol(report: dict[str, Any]) -> str | None:
    """How a model's report was predicted, in words: windows, stride, scale and test-time
    augmentation (None for a report of label maps or one that does not say)."""
    window = report.get("source", {}).get("window")
    if not isinstance(window, dict) or "size" not in window:
        return None
    (h, w), (sh, sw) = window["size"], window.get("stride") or ("?", "?")
    text = f"windows {w}x{h} every {sw}x{sh}, scale {window.get('scale')}"
    tta = window.get("tta")
    if not tta:
        return text + ", one copy (no test-time augmentation)"
    ratios = ", ".join(f"{r:g}" for r in tta.get("scales", []))
    size = f", S {tta['size']}" if tta.get("size") else ""
    mirror = " and the mirror" if tta.get("flip") else ""
    return (
        text + f", test-time augmentation ({tta.get('rule')} rule{size}): ratios {ratios}{mirror}"
    )


def comparison_warnings(reports: Sequence[dict[str, Any]], names: Sequence[str]) -> list[str]:
    """What makes the side-by-side rows not comparable: palettes, binning, bin ranges, and the
    evaluation protocol (test-time augmentation: a gap then includes what it buys)."""
    out = []
    first, name0 = reports[0], names[0]
    for report, name in itertools.islice(zip(reports, names, strict=True), 1, None):
        t0 = (first.get("source", {}).get("window") or {}).get("tta")
        t1 = (report.get("source", {}).get("window") or {}).get("tta")
        if t0 != t1 and evaluation_protocol(first) and evaluation_protocol(report):
            out.append(
                f"evaluation protocols differ: {name0} {evaluation_protocol(first)}; {name} "
                f"{evaluation_protocol(report)}; the gaps include the augmentation's effect"
            )
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


def not_comparable(a: EvalResult, b: EvalResult, name_a: str, name_b: str) -> str | None:
    """Why B's gap to A means nothing (None: it does): other classes, or one run seen twice
    (a report and its own re-binning or merge: a shared ``report_id`` in their lineages).
    Predictions that agree do not make one run: two runs that agree get a gap of 0."""
    if a.classes != b.classes:
        return (f"{name_b} and {name_a} score different class sets ({len(b.classes)} vs "
                f"{len(a.classes)} classes, other palettes): their mIoUs average different "
                "classes")  # fmt: skip
    shared = sorted(set(a.lineage) & set(b.lineage))
    if shared:
        return (f"{name_b} and {name_a} are one run seen twice (both come from report "
                f"{shared[0]}: a report and its own re-binning, merge or copy): a model "
                "against itself")  # fmt: skip
    return None


def report_bins(result: EvalResult, report: dict[str, Any]) -> list[Bin]:
    """The bins of a report, re-derived from its per-image table and its recorded binning."""
    binning = report["source"].get("binning", {})
    values = result.complexity.get(binning.get("measure", ""))
    if values is None or not binning.get("method"):
        return []
    edges = binning["edges"] if binning["method"] == "fixed" else None
    bins = int(binning.get("bins") or 1)
    return choose_bins(values, result.paths, binning["measure"], bins=bins, edges=edges)[0]


def cluster_unit(results: Sequence[EvalResult], names: Sequence[str], wanted: str | None) -> str:
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
        results: per-image tables (:func:`claravid.eval.report.files.load_result`), baseline first.
        reports: their ``report.json`` (for the binning and the bin names).
        names: how each report is named in the output.
        settings: resamples, level, seed and the cluster unit.
    """
    for result in results:  # before anything is allocated: unpaired gaps draw each report's
        settings.check_memory(result.cluster_labels(settings.cluster))
    base, base_report = results[0], reports[0]
    base_ids = _ids(base, settings.cluster)
    base_bins = report_bins(base, base_report)
    comparisons = []
    for j, (result, report, name) in enumerate(
        zip(results[1:], reports[1:], names[1:], strict=True), 1
    ):
        reason = not_comparable(base, result, names[0], name)
        if reason is not None:
            comparisons.append({"report": name, "comparable": False, "reason": reason,
                                "paired": False, "overall": None, "bins": []})  # fmt: skip
            continue
        pair = _Pair(base, result, base_ids, settings)
        other_bins = report_bins(result, report)
        entry: dict[str, Any] = {
            "report": name,
            "comparable": True,
            "paired": pair.paired,
            "overall": pair.gap(
                range(len(base.paths)), range(len(result.paths)), f"compare:{j}:overall"
            ),
            "bins": [],
        }
        for a, b in zip(base_bins, other_bins, strict=False):
            row = pair.gap(a.indices, b.indices, f"compare:{j}:bin:{a.name}")
            entry["bins"].append({"name": a.name, **row})
        entry["quality"], entry["missing"] = {}, {}
        for measure in QUALITY:
            why = _missing(base.quality, result.quality, measure, names[0], name)
            if why is not None:
                entry["missing"][measure] = why
                continue
            sets: list[tuple[str, Sequence[int], Sequence[int]]] = [
                ("overall", range(len(base.paths)), range(len(result.paths)))
            ]
            sets += [(a.name, a.indices, b.indices)
                     for a, b in zip(base_bins, other_bins, strict=False)]  # fmt: skip
            rows = [pair.quality_gap(measure, ma, mb, f"compare:{j}:{where}:{measure}")
                    for where, ma, mb in sets]  # fmt: skip
            entry["quality"][measure] = {
                "overall": rows[0],
                "bins": [{"name": where, **row} for (where, _, _), row in zip(sets[1:], rows[1:],
                                                                              strict=True)],
            }  # fmt: skip
        entry["predictable"] = _predictable_gaps(pair, base, result, base_bins, other_bins,
                                                 f"compare:{j}")  # fmt: skip
        if not pair.paired:
            entry["note"] = (
                f"{name} and {names[0]} cover different images: unpaired comparison, each "
                "resampled independently"
            )
        comparisons.append(entry)
    return {
        "baseline": names[0],
        "comparisons": comparisons,
        "uncertainty": settings.describe(count_clusters(base_ids)),
    }


def shared_predictable(a: EvalResult, b: EvalResult) -> list[int] | None:
    """The classes both reports' models can predict (indices), when some class is not; None
    when every class is predictable or a report does not say."""
    first, second = a.source.get("predictable"), b.source.get("predictable")
    if not isinstance(first, list) or not isinstance(second, list):
        return None
    both = set(first) & set(second)
    subset = [i for i, c in enumerate(a.classes) if c in both]
    return None if len(subset) in (0, len(a.classes)) else subset


def _predictable_gaps(
    pair: _Pair, a: EvalResult, b: EvalResult, bins_a: Sequence[Bin], bins_b: Sequence[Bin],
    stream: str,
) -> dict[str, Any] | None:  # fmt: skip
    """The mIoU gap over the classes both models can predict, overall and per bin, apart from
    the all-class gap (None when every class is predictable)."""
    subset = shared_predictable(a, b)
    if subset is None:
        return None
    statistic = subset_statistic(len(a.classes), subset)
    rows = [pair.subset_gap(statistic, range(len(a.paths)), range(len(b.paths)),
                            f"{stream}:overall:predictable")]  # fmt: skip
    rows += [pair.subset_gap(statistic, x.indices, y.indices, f"{stream}:bin:{x.name}:predictable")
             for x, y in zip(bins_a, bins_b, strict=False)]  # fmt: skip
    return {
        "classes": [a.classes[i] for i in subset],
        "resamples": pair.settings.resamples,
        "overall": rows[0],
        "bins": [{"name": x.name, **row} for x, row in zip(bins_a, rows[1:], strict=False)],
    }


def _missing(
    a: QualityTable | None, b: QualityTable | None, measure: str, name_a: str, name_b: str
) -> str | None:
    """Why ``measure`` cannot be compared between A and B (None: both computed it alike)."""
    lacking = []
    for table, name in ((a, name_a), (b, name_b)):
        status = COMPUTED if table is None else table.status[measure]
        if table is None or status != COMPUTED:
            reason = None if table is None else table.reasons.get(measure)
            state = "not measured" if table is None else status
            lacking.append(f"{state} in {name}" + (f" ({reason})" if reason else ""))
    if lacking:
        return "; ".join(lacking)
    if a is None or b is None:  # a missing table is lacking above
        raise ValueError(f"{measure}: a report without quality table passed as computed")
    if a.settings.get(measure, {}) != b.settings.get(measure, {}):
        return (f"computed with other settings: {name_a} {a.settings.get(measure)}, {name_b} "
                f"{b.settings.get(measure)}")  # fmt: skip
    return None


def _computed_rows(result: EvalResult, measure: str) -> np.ndarray:
    """The per-image sums of ``measure``, which :func:`_missing` found computed."""
    rows = None if result.quality is None else measure_rows(result.quality, measure)
    if rows is None:
        raise ValueError(f"{measure} is not computed in this report: it cannot be compared")
    return rows


class _Pair:
    """Baseline A and report B: paired (same images) or not, and the gap of two image sets."""

    def __init__(self, a: EvalResult, b: EvalResult, a_ids: np.ndarray, settings: Bootstrap):
        self.a, self.b, self.a_ids, self.settings = a, b, a_ids, settings
        # Images are known by their key below the data root, so two spellings of one root
        # (a symlink, ../s) still pair.
        a_keys, b_keys = a.image_ids(), b.image_ids()
        self.paired = sorted(b_keys) == sorted(a_keys) and b.classes == a.classes
        if self.paired:
            # B's rows in A's image order; both resample A's clusters.
            where = {p: i for i, p in enumerate(b_keys)}
            order = np.asarray([where[p] for p in a_keys], dtype=np.int64)
            self.order = order
            self.b_conf = b.confusions[order]
            self.b_to_a = np.argsort(order)
        else:
            self.b_ids = _ids(b, settings.cluster)

    def _same_images(self, members_a: Sequence[int], members_b: Sequence[int]) -> bool:
        return self.paired and sorted(members_a) == sorted(int(self.b_to_a[i]) for i in members_b)

    def quality_gap(
        self, measure: str, members_a: Sequence[int], members_b: Sequence[int], stream: str
    ) -> dict[str, Any]:
        """The gaps B − A of ``measure``'s compared statistics (:data:`COMPARED`): paired over
        the same images, else each report resampled on its own."""
        statistic, all_names = STATISTICS[measure]
        names = COMPARED[measure]
        picked = [all_names.index(n) for n in names]

        def chosen(sums: np.ndarray) -> np.ndarray:
            return np.asarray(statistic(sums)).reshape(len(sums), -1)[:, picked]

        rows_a = _computed_rows(self.a, measure)
        rows_b = _computed_rows(self.b, measure)
        if self._same_images(members_a, members_b):
            return paired_sums_gap(rows_a, rows_b[self.order], self.a_ids, members_a,
                                   self.settings, chosen, names, stream=stream)  # fmt: skip
        b_ids = _ids(self.b, self.settings.cluster) if self.paired else self.b_ids
        return unpaired_sums_gap(rows_a, self.a_ids, members_a, rows_b, b_ids, members_b,
                                 self.settings, chosen, names, stream=stream)  # fmt: skip

    def subset_gap(
        self, statistic: Any, members_a: Sequence[int], members_b: Sequence[int], stream: str
    ) -> dict[str, Any]:
        """The gap B − A of an mIoU over a subset of classes
        (:func:`~claravid.eval.analysis.predictable.subset_statistic`), paired where
        :meth:`gap` is."""
        rows_a = confusion_features(self.a.confusions)
        if self._same_images(members_a, members_b):
            rows_b = confusion_features(self.b_conf)
            out = paired_sums_gap(rows_a, rows_b, self.a_ids, members_a, self.settings,
                                  statistic, ["miou"], stream=stream)  # fmt: skip
        else:
            b_ids = _ids(self.b, self.settings.cluster) if self.paired else self.b_ids
            out = unpaired_sums_gap(rows_a, self.a_ids, members_a,
                                    confusion_features(self.b.confusions), b_ids, members_b,
                                    self.settings, statistic, ["miou"], stream=stream)  # fmt: skip
        return out["miou"]

    def gap(self, members_a: Sequence[int], members_b: Sequence[int], stream: str) -> dict:
        """The gap B − A of A's ``members_a`` and B's ``members_b``; paired when the two
        reports cover the same images and the two sets are the same images."""
        if self._same_images(members_a, members_b):
            out = paired_gap(self.a.confusions, self.b_conf, self.a_ids, members_a,
                             self.settings, stream=stream)  # fmt: skip
            return {"paired": True, **out}
        b_ids = _ids(self.b, self.settings.cluster) if self.paired else self.b_ids
        out = unpaired_gap(self.a.confusions, self.a_ids, members_a, self.b.confusions, b_ids,
                           members_b, self.settings, stream=stream)  # fmt: skip
        return {"paired": False, **out}


def _ids(result: EvalResult, unit: str) -> np.ndarray:
    return cluster_ids(result.cluster_labels(unit))

"""The measures beyond mIoU of a set of images: Boundary IoU, calibration, cross-view consistency.

Each is a statistic of the set's summed per-image rows
(:mod:`claravid.eval.analysis.quality_table`), so it is computed for a bin, a group, the whole
split or a bootstrap resample alike:

- **mBoundaryIoU**: per class, summed boundary intersections over summed unions; the NaN-mean
  over classes with a union (as mIoU);
- **ECE** = Σ_b |correct_b − confidence_b| / N over the 15 confidence bins (= Σ_b (n_b / N) ·
  |acc_b − conf_b|); **MCE** = the largest |acc_b − conf_b| of a non-empty bin;
- **consistency** of predictions = kept pixels whose predictions agree / kept pixels, summed
  over the set's pairs (a pair belongs to its frame t); **TC** = the NaN-mean over classes of
  the IoU between the predictions of t and of s carried back to t; both computed on the ground
  truth too, the ceiling.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.metrics import finite_or_none
from claravid.eval.analysis.quality_table import (
    BOUNDARY,
    CALIBRATION,
    CONSISTENCY,
    PAIR_FIXED,
    QUALITY,
    QualityTable,
)
from claravid.eval.analysis.sum_intervals import Statistic, point_values, sums_interval

#: The statistic of each measure that paired comparisons test, and whether higher is better.
HEADLINE: dict[str, tuple[str, bool]] = {
    BOUNDARY: ("miou", True),
    CALIBRATION: ("ece", False),
    CONSISTENCY: ("agreement", True),
}


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


def _nanmean_rows(values: np.ndarray) -> np.ndarray:
    """The NaN-mean of each row; NaN for a row without a finite value."""
    finite = np.isfinite(values)
    count = finite.sum(axis=1)
    total = np.where(finite, values, 0.0).sum(axis=1)
    return _ratio(total, count.astype(np.float64))


def boundary_stat(sums: np.ndarray) -> np.ndarray:
    """mBoundaryIoU [R, 1] of summed boundary rows [R, 2K] (intersections, then unions)."""
    k = sums.shape[1] // 2
    return _nanmean_rows(_ratio(sums[:, :k], sums[:, k:]))[:, None]


def calibration_stat(sums: np.ndarray) -> np.ndarray:
    """ECE and MCE [R, 2] of summed calibration rows [R, 3B] (count, confidence sum, correct)."""
    b = sums.shape[1] // 3
    count, conf, correct = sums[:, :b], sums[:, b : 2 * b], sums[:, 2 * b :]
    ece = _ratio(np.abs(correct - conf).sum(axis=1), count.sum(axis=1))
    gap = np.where(count > 0, np.abs(_ratio(correct, count) - _ratio(conf, count)), -np.inf)
    mce = gap.max(axis=1)
    return np.stack([ece, np.where(np.isfinite(mce), mce, np.nan)], axis=1)


def consistency_stat(sums: np.ndarray) -> np.ndarray:
    """Agreement and TC of the predictions, then of the ground truth [R, 4], of summed pair
    rows [R, 3 + 4K]."""
    f = len(PAIR_FIXED)
    k = (sums.shape[1] - f) // 4
    kept, agree, agree_gt = sums[:, 0], sums[:, 1], sums[:, 2]
    block = [sums[:, f + j * k : f + (j + 1) * k] for j in range(4)]
    return np.stack([_ratio(agree, kept), _nanmean_rows(_ratio(block[0], block[1])),
                     _ratio(agree_gt, kept), _nanmean_rows(_ratio(block[2], block[3]))],
                    axis=1)  # fmt: skip


#: Per measure: its statistic and the names of its columns.
STATISTICS: dict[str, tuple[Statistic, tuple[str, ...]]] = {
    BOUNDARY: (boundary_stat, ("miou",)),
    CALIBRATION: (calibration_stat, ("ece", "mce")),
    CONSISTENCY: (consistency_stat, ("agreement", "tc", "agreement_gt", "tc_gt")),
}


def measure_rows(table: QualityTable, name: str) -> np.ndarray | None:
    """The per-image rows of sums [N, D] of measure ``name`` (None when not computed)."""
    if not table.computed(name):
        return None
    if name in (BOUNDARY, CALIBRATION):
        sums = table.computed_sums(name)
        return sums.reshape(len(sums), -1)
    return table.computed_pairs().sums


def _per_class(values: np.ndarray, classes: Sequence[str]) -> dict[str, float | None]:
    return {c: finite_or_none(v) for c, v in zip(classes, values, strict=True)}


def _details(table: QualityTable, name: str, summed: np.ndarray, classes: Sequence[str],
             members: Sequence[int]) -> dict[str, Any]:  # fmt: skip
    """What a row shows of a measure beside its headline statistics."""
    k = len(classes)
    if name == BOUNDARY:
        return {"per_class_iou": _per_class(_ratio(summed[:k], summed[k:]), classes)}
    if name == CALIBRATION:
        b = len(summed) // 3
        count, conf, correct = summed[:b], summed[b : 2 * b], summed[2 * b :]
        return {
            "num_pixels": int(count.sum()),
            "reliability": {
                "count": [int(c) for c in count],
                "confidence": [finite_or_none(v) for v in _ratio(conf, count)],
                "accuracy": [finite_or_none(v) for v in _ratio(correct, count)],
            },
        }
    f = len(PAIR_FIXED)
    blocks = [summed[f + j * k : f + (j + 1) * k] for j in range(4)]
    return {
        "pairs": table.computed_pairs().counts(members),
        "kept_pixels": int(summed[0]),
        "per_class_tc": _per_class(_ratio(blocks[0], blocks[1]), classes),
        "per_class_tc_gt": _per_class(_ratio(blocks[2], blocks[3]), classes),
    }


def quality_entries(
    table: QualityTable | None,
    members: Sequence[int],
    classes: Sequence[str],
    *,
    clusters: np.ndarray | None = None,
    bootstrap: Bootstrap | None = None,
    stream: str = "",
) -> dict[str, dict[str, Any]]:
    """A row's entries of the computed measures: ``{measure: {statistics, intervals, details}}``.

    Args:
        table: the per-image sums (None: nothing computed).
        members: the images of the row (a bin, a group, all).
        classes: the K class names.
        clusters: int [N] cluster ids, with ``bootstrap``: the intervals (``<statistic>_ci``).
        bootstrap: interval settings; None: no intervals.
        stream: the row's generator name; each measure draws from ``<stream>:<measure>``.
    """
    if table is None:
        return {}
    out = {}
    for name in QUALITY:
        rows = measure_rows(table, name)
        if rows is None:
            continue
        statistic, names = STATISTICS[name]
        values = point_values(rows, members, statistic)
        entry: dict[str, Any] = {n: finite_or_none(v) for n, v in zip(names, values, strict=True)}
        if bootstrap is not None and clusters is not None:
            entry.update(sums_interval(rows, clusters, members, bootstrap, statistic, names,
                                       stream=f"{stream}:{name}"))  # fmt: skip
        summed = np.asarray(rows, np.float64)[np.asarray(members, np.int64)].sum(axis=0)
        entry.update(_details(table, name, summed, classes, members))
        out[name] = entry
    return out


def image_values(table: QualityTable | None) -> dict[str, np.ndarray]:
    """Each image's own value of the computed measures (float64 [N], NaN where undefined):
    ``boundary_iou``, ``ece``, ``consistency`` and ``consistency_gt`` (of the image's pair)."""
    if table is None:
        return {}
    out = {}
    for name in QUALITY:
        rows = measure_rows(table, name)
        if rows is None:
            continue
        values = STATISTICS[name][0](np.asarray(rows, np.float64))
        if name == BOUNDARY:
            out["boundary_iou"] = values[:, 0]
        elif name == CALIBRATION:
            out["ece"] = values[:, 0]
        else:
            out["consistency"], out["consistency_gt"] = values[:, 0], values[:, 2]
    return out


def quality_summary(table: QualityTable | None, reason: str) -> dict[str, dict[str, Any]]:
    """The report's top-level ``quality`` entry: per measure its status, why it is not computed
    (``reason`` when there is no table at all), and how it was computed."""
    if table is None:
        table = QualityTable.absent(reason)
    out = {}
    for name in QUALITY:
        entry: dict[str, Any] = {"status": table.status[name], "reason": table.reasons.get(name),
                                 "settings": dict(table.settings.get(name, {}))}  # fmt: skip
        if name == CONSISTENCY and table.pairs is not None:
            entry["pairs"] = table.pairs.counts()
            entry["unavailable"] = sorted({r for r in table.pairs.reason if r})[:5]
        out[name] = entry
    return out

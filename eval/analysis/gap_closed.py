"""What domain adaptation closes: the fraction of the source-to-oracle gap an adapted model
recovers, with cluster bootstrap intervals.

Three reports on the same images and palette: a *source-only* model (trained on ClaraVid), an
*adapted* one, and an *oracle* trained on the target data itself. Per set of images (overall,
each complexity bin) the fraction closed is

    (mIoU_adapted − mIoU_source) / (mIoU_oracle − mIoU_source),

1 when adaptation reaches the oracle, 0 when it gains nothing, negative when it loses; per
class the same of each class's IoU over all images. Each mIoU comes from the set's summed
confusion. The interval resamples the same clusters for all three models (one draw, the three
confusions summed side by side), so the spread shared by the models cancels, as in a paired
gap (:mod:`claravid.eval.analysis.gaps`). Where the oracle is no better than the source-only
model the fraction is undefined (None) and a note says so; where the oracle's gap has an
interval that reaches 0 the fraction's interval is unbounded in principle, and a note says
that too. Bins are the source-only report's, applied to the same images of the other two.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from claravid.eval.analysis.bins import Bin
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    confusion_features,
    count_clusters,
)
from claravid.eval.analysis.predictable import subset_statistic
from claravid.eval.analysis.sum_intervals import Statistic, point_values, sums_interval
from claravid.eval.analysis.table import EvalResult
from claravid.infra.cli import UsageError

#: A gap smaller than this (in IoU) divides nothing: the fraction is undefined.
TINY_GAP = 1e-12


def _fraction(adapted: np.ndarray, source: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    gap = oracle - source
    ok = np.isfinite(gap) & (np.abs(gap) > TINY_GAP) & np.isfinite(adapted)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ok, (adapted - source) / np.where(ok, gap, 1.0), np.nan)


def _class_iou(features: np.ndarray, k: int) -> np.ndarray:
    tp, truth, predicted = features[:, :k], features[:, k : 2 * k], features[:, 2 * k :]
    union = truth + predicted - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, tp / np.where(union > 0, union, 1.0), np.nan)


def closed_statistic(k: int, subset: Sequence[int] | None, per_class: bool) -> Statistic:
    """Summed features of the three models side by side [R, 9K] (source, adapted, oracle,
    each :func:`~claravid.eval.analysis.bootstrap.confusion_features`) -> [R, S]: the mIoU
    fraction closed, the oracle's mIoU gap, then with ``subset`` the fraction over those
    classes, then with ``per_class`` each class's fraction and each class's oracle gap."""
    everything, chosen = subset_statistic(k), None
    if subset is not None:
        chosen = subset_statistic(k, subset)

    def statistic(sums: np.ndarray) -> np.ndarray:
        sums = np.asarray(sums, dtype=np.float64).reshape(-1, 9 * k)
        s, a, o = sums[:, : 3 * k], sums[:, 3 * k : 6 * k], sums[:, 6 * k :]
        ms, ma, mo = (everything(x)[:, 0] for x in (s, a, o))
        columns = [_fraction(ma, ms, mo), mo - ms]
        if chosen is not None:
            columns.append(_fraction(*(chosen(x)[:, 0] for x in (a, s, o))))
        out = np.stack(columns, axis=1)
        if per_class:
            cs, ca, co = (_class_iou(x, k) for x in (s, a, o))
            out = np.concatenate([out, _fraction(ca, cs, co), co - cs], axis=1)
        return out

    return statistic


def _aligned(base: EvalResult, other: EvalResult, name: str, base_name: str) -> np.ndarray:
    """``other``'s rows in ``base``'s image order.

    Raises:
        UsageError: other classes or other images (gap closed compares one data set).
    """
    if other.classes != base.classes:
        raise UsageError(
            f"gap closed needs one palette: {name} scores {len(other.classes)} classes "
            f"({other.palette}), {base_name} {len(base.classes)} ({base.palette})"
        )
    a_keys, b_keys = base.image_ids(), other.image_ids()
    if sorted(a_keys) != sorted(b_keys):
        raise UsageError(
            f"gap closed needs the same images in every report: {name} covers "
            f"{len(b_keys)} images, {base_name} {len(a_keys)}, not the same ones; evaluate "
            "all three on the same data and split"
        )
    where = {key: i for i, key in enumerate(b_keys)}
    return np.asarray([where[key] for key in a_keys], dtype=np.int64)


def _entry(
    values: np.ndarray, found: dict[str, Any], names: Sequence[str], j: int
) -> dict[str, Any]:
    def pick(n: str) -> Any:
        if n not in names:
            return None
        v = float(values[names.index(n)])
        return v if np.isfinite(v) else None

    closed, gap = f"closed{j}", f"oracle_gap{j}"
    return {
        "closed": pick(closed),
        "closed_ci": found.get(f"{closed}_ci"),
        "oracle_gap": pick(gap),
        "oracle_gap_ci": found.get(f"{gap}_ci"),
        "ci_note": found.get("ci_note"),
    }


def _closed_figures(
    rows: np.ndarray,
    ids: np.ndarray,
    members: list[int],
    settings: Bootstrap,
    shape: tuple[int, list[int] | None, bool],
    counts: np.ndarray | None,
    stream: str,
) -> tuple[Any, dict[str, Any], list[str]]:
    """One row's (overall or a bin's) closed fractions: the point values, their intervals and
    the labels naming them; ``shape`` is (classes, the predictable subset, per class)."""
    k, subset, per_class = shape
    statistic = closed_statistic(k, subset, per_class)
    labels = ["closed0", "oracle_gap0"] + (["closed1"] if subset is not None else [])
    if per_class:
        labels += [f"closed{2 + c}" for c in range(k)]
        labels += [f"oracle_gap{2 + c}" for c in range(k)]
    values = point_values(rows, members, statistic)
    found = sums_interval(rows, ids, members, settings, statistic, labels, counts=counts,
                          stream=stream)  # fmt: skip
    return values, found, labels


def gap_closed(
    source: EvalResult,
    adapted: Sequence[EvalResult],
    oracle: EvalResult,
    names: Sequence[str],
    bins: Sequence[Bin],
    settings: Bootstrap,
    *,
    predictable: Sequence[str] | None = None,
    counts: np.ndarray | None = None,
) -> dict[str, Any]:
    """The fraction of the source-to-oracle gap each adapted report closes.

    Args:
        source: the source-only model's per-image table.
        adapted: one table per adapted model.
        oracle: the target-supervised model's table.
        names: the reports' names: source, each adapted, oracle.
        bins: the complexity bins (image indices in ``source``'s order).
        settings: resamples, level, seed and cluster unit.
        predictable: also the fraction over these classes only (structural zeros left out).
        counts: fixed draw counts [R, C] over all images' clusters (tests).

    Returns:
        ``{"source", "oracle", "adapted": [{"report", "overall", "bins", "classes",
        "predictable"}], "notes", "uncertainty"}``; each figure ``{"closed", "closed_ci",
        "oracle_gap", "oracle_gap_ci", "ci_note"}``.

    Raises:
        UsageError: the reports differ in classes or images.
    """
    k, classes = len(source.classes), source.classes
    ids = cluster_ids(source.cluster_labels(settings.cluster))
    settings.check_memory(count_clusters(ids))
    oracle_rows = confusion_features(
        oracle.confusions[_aligned(source, oracle, names[-1], names[0])]
    )
    subset = None
    if predictable is not None and set(predictable) != set(classes):
        subset = [i for i, c in enumerate(classes) if c in set(predictable)]
    out: dict[str, Any] = {"source": names[0], "oracle": names[-1], "adapted": [], "notes": []}
    for j, (table, name) in enumerate(zip(adapted, names[1:-1], strict=True)):
        order = _aligned(source, table, name, names[0])
        rows = np.concatenate(
            [
                confusion_features(source.confusions),
                confusion_features(table.confusions[order]),
                oracle_rows,
            ],
            axis=1,
        )
        entry: dict[str, Any] = {"report": name, "bins": []}
        for where, members, per_class in [
            ("overall", list(range(len(ids))), True),
            *((b.name, list(b.indices), False) for b in bins),
        ]:
            local = None if counts is None or where != "overall" else counts
            values, found, labels = _closed_figures(
                rows, ids, members, settings, (k, subset, per_class), local, f"closed:{j}:{where}"
            )
            figure = _entry(values, found, labels, 0)
            if where != "overall":
                entry["bins"].append({"name": where, **figure})
                continue
            entry["overall"] = figure
            entry["classes"] = {
                c: _entry(values, found, labels, 2 + i) for i, c in enumerate(classes)
            }
            entry["predictable"] = None if subset is None else {
                "classes": [classes[i] for i in subset],
                "closed": _entry(values, found, labels, 1)["closed"],
                "closed_ci": found.get("closed1_ci"),
            }  # fmt: skip
        out["adapted"].append(entry)
    out["notes"] = _notes(out["adapted"][:1], names)
    out["uncertainty"] = settings.describe(count_clusters(ids))
    return out


def _notes(entries: Sequence[dict[str, Any]], names: Sequence[str]) -> list[str]:
    """Where the fraction is undefined or unstable: the oracle no better than the source-only
    model, or an oracle gap whose interval reaches 0 (the same for every adapted report)."""
    notes = []
    for entry in entries:
        for row in [{**entry["overall"], "name": "overall"}, *entry["bins"]]:
            gap, ci = row.get("oracle_gap"), row.get("oracle_gap_ci")
            if gap is None or gap <= TINY_GAP:
                notes.append(
                    f"{row['name']}: {names[-1]} is not better than {names[0]} "
                    "(mIoU): the fraction is undefined"
                )
            elif ci and ci[0] <= 0:
                notes.append(
                    f"{row['name']}: the interval of {names[-1]} − {names[0]} reaches 0: "
                    "the fraction's interval is unstable"
                )
    return notes

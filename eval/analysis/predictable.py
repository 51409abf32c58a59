"""Classes a model cannot predict: the mIoU cap they imply, and mIoU over the others.

A palette whose ClaraVid side maps no ClaraVid class to some class (UDD6's Facade, VDD's wall)
leaves that class out of reach of every model trained on ClaraVid through it, and of a fine
model scored through it: wherever it is in the ground truth its IoU is 0 (TP = 0 and the union
is not empty), a *structural zero*. Over a set of images whose ground truth holds P classes, U
of them unpredictable, the mIoU is at most (P − U) / P, reached when every other class is
perfect and nothing is predicted outside the ground truth.

Every row of a report (overall, bins, groups) then also gives ``miou_predictable``, the
NaN-mean of the IoU over the predictable classes only (each IoU from the full confusion, so a
pixel of an unpredictable class predicted as another still counts as that class's false
positive), with its cluster bootstrap interval, and ``miou_cap`` with the unpredictable
classes its ground truth holds (``unpredictable_present``). A user subset works the same way
(:func:`subset_statistic`). All numpy, from per-image confusions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from claravid.eval.analysis.bins import Bin
from claravid.eval.analysis.bootstrap import Bootstrap, cluster_ids, confusion_features
from claravid.eval.analysis.metrics import finite_or_none
from claravid.eval.analysis.sum_intervals import Statistic, point_values, sums_interval


def subset_statistic(k: int, subset: Sequence[int] | None = None) -> Statistic:
    """mIoU over the classes ``subset`` (all K when None) of summed confusion features
    [R, 3K] (:func:`~claravid.eval.analysis.bootstrap.confusion_features`) -> [R, 1]: the
    NaN-mean of each class's TP / (TP + FP + FN), classes with union 0 left out."""
    index = np.arange(k) if subset is None else np.asarray(list(subset), dtype=np.int64)

    def statistic(sums: np.ndarray) -> np.ndarray:
        sums = np.asarray(sums, dtype=np.float64).reshape(-1, 3 * k)
        tp, truth, predicted = sums[:, index], sums[:, k + index], sums[:, 2 * k + index]
        union = truth + predicted - tp
        present = union > 0
        iou = np.where(present, tp / np.where(present, union, 1.0), 0.0)
        count = present.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, iou.sum(axis=1) / np.maximum(count, 1), np.nan)[:, None]

    return statistic


def miou_cap(confusion: np.ndarray, predictable: np.ndarray) -> tuple[float | None, list[int]]:
    """The highest mIoU a model that predicts only ``predictable`` (bool [K]) can reach on a
    summed confusion [K, K], and the unpredictable classes its ground truth holds.

    None when the ground truth holds no class at all.
    """
    truth = np.asarray(confusion).sum(axis=1) > 0
    present = int(truth.sum())
    missing = np.flatnonzero(truth & ~np.asarray(predictable, dtype=bool)).tolist()
    return ((present - len(missing)) / present if present else None), missing


def predictable_mask(classes: Sequence[str], names: Sequence[str] | None) -> np.ndarray | None:
    """bool [K] of the predictable classes by name; None when every class is predictable or
    nothing is known (no structural zero to state)."""
    if names is None:
        return None
    mask = np.asarray([c in set(names) for c in classes], dtype=bool)
    return None if mask.all() or not mask.any() else mask


def subset_mask(classes: Sequence[str], names: Sequence[str] | None) -> np.ndarray | None:
    """bool [K] of a user's class subset (``ReportSettings.classes``); None without one.

    Raises:
        ValueError: a name that is not one of ``classes``, or no name at all.
    """
    if names is None:
        return None
    unknown = [n for n in names if n not in classes]
    if unknown or not names:
        raise ValueError(
            f"--classes {','.join(names)}: {', '.join(unknown) or 'no class'} not in the "
            f"palette's classes ({', '.join(classes)})"
        )
    return np.asarray([c in set(names) for c in classes], dtype=bool)


def add_predictable(
    report: dict[str, Any],
    confusions: np.ndarray,
    predictable: np.ndarray | None,
    bin_list: Sequence[Bin],
    groups: Mapping[str, Sequence[int]],
    clusters: Sequence[str],
    bootstrap: Bootstrap | None,
    *,
    key: str = "predictable",
) -> None:
    """Add ``miou_predictable`` (with ``miou_predictable_ci`` when ``bootstrap``), ``miou_cap``
    and ``unpredictable_present`` to every row of ``report`` in place (nothing when
    ``predictable`` is None). Each row draws from ``<row stream>:predictable``. With another
    ``key`` (``classes``: a user's subset) only ``miou_<key>`` and its interval."""
    if predictable is None:
        return
    classes = report["classes"]
    k = len(classes)
    features = confusion_features(confusions)
    statistic = subset_statistic(k, np.flatnonzero(predictable).tolist())
    ids = cluster_ids(clusters)
    sets: list[tuple[dict[str, Any], Sequence[int], str]] = [
        (report["overall"], range(len(confusions)), "overall")
    ]
    sets += [
        (row, b.indices, f"bin:{b.name}") for b, row in zip(bin_list, report["bins"], strict=True)
    ]
    sets += [
        (row, members, f"group:{name}")
        for (name, members), row in zip(groups.items(), report["groups"], strict=True)
    ]
    name = f"miou_{key}"
    for row, members, stream in sets:
        members = list(members)
        value = point_values(features, members, statistic)[0] if members else np.nan
        row[name] = finite_or_none(float(value))
        if bootstrap is not None and members:
            found = sums_interval(
                features, ids, members, bootstrap, statistic, [name], stream=f"{stream}:{key}"
            )
            row[f"{name}_ci"] = found[f"{name}_ci"]
        if key == "predictable":
            summed = confusions[members].sum(axis=0) if members else np.zeros((k, k), np.int64)
            cap, missing = miou_cap(summed, predictable)
            row["miou_cap"] = cap
            row["unpredictable_present"] = [classes[i] for i in missing]

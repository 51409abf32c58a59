"""From per-image confusions and complexities to the report's numbers.

Overall, per complexity bin and per group (mission or viewpoint): number of images, range, mIoU,
per-class IoU and pixel accuracy, each from the group's summed confusion (see
docs/report-format.md); per image: its own mIoU and pixel accuracy; Pearson and Spearman
correlations between each complexity measure and per-image mIoU, with n. With a
:class:`~claravid.eval.analysis.bootstrap.Bootstrap` and a cluster label per image, every mIoU,
pixel accuracy and correlation also gets its cluster percentile bootstrap interval (``miou_ci``,
``pixel_acc_ci``, ``pearson_ci``, ``spearman_ci``; ``ci_note`` says why one is null). With the
sums of the measures beyond mIoU (:mod:`claravid.eval.analysis.quality`), every row also carries
its mBoundaryIoU, ECE and MCE, and cross-view consistency, each with its interval. Everything
here is numpy on finished results, so a report can be re-binned or merged from saved confusions
without running a model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from claravid.data.ignore import IGNORE_INDEX
from claravid.eval.analysis.bins import Bin, choose_bins
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    confusion_features,
    confusion_interval,
    correlation_interval,
    count_clusters,
)
from claravid.eval.analysis.complexity_measures import PRIMARY_MEASURE
from claravid.eval.analysis.metrics import (
    CONVENTION,
    confusion_scores,
    finite_or_none,
    mean_iou,
    pixel_accuracy,
)
from claravid.eval.analysis.predictable import add_predictable, predictable_mask, subset_mask
from claravid.eval.analysis.quality import image_values, quality_entries, quality_summary
from claravid.eval.analysis.quality_table import QualityTable
from claravid.eval.analysis.stats import correlation, group_profile, order_warnings


def _group_row(
    name: str,
    members: Sequence[int],
    confusions: np.ndarray,
    classes: Sequence[str],
    values: np.ndarray | None,
) -> dict[str, Any]:
    conf = confusions[list(members)].sum(axis=0) if len(members) else np.zeros_like(confusions[0])
    row: dict[str, Any] = {"name": name, "num_images": len(members)}
    if values is not None:
        vals = values[list(members)]
        row["lo"] = finite_or_none(float(vals.min())) if len(vals) else None
        row["hi"] = finite_or_none(float(vals.max())) if len(vals) else None
    row.update(confusion_scores(conf, classes))
    return row


def stratify(
    paths: Sequence[str],
    confusions: np.ndarray,
    classes: Sequence[str],
    complexity: Mapping[str, ArrayLike] | None = None,
    *,
    bins: int = 3,
    edges: Sequence[float] | None = None,
    groups: Mapping[str, Sequence[int]] | None = None,
    clusters: Sequence[str] | None = None,
    bootstrap: Bootstrap | None = None,
    quality: QualityTable | None = None,
    predictable: Sequence[str] | None = None,
    subset: Sequence[str] | None = None,
) -> dict[str, Any]:
    """The report's numbers (everything but the ``source`` and palette name).

    Args:
        paths: one per image (the RGB file), in the order of ``confusions``.
        confusions: int64 [N,K,K], one confusion per image.
        classes: the K class names.
        complexity: measure name (``delent``, ``glcment``, ``pixent``) -> one value per image;
            bins use ``delent`` (or the first measure given).
        bins: K quantile bins (ignored when ``edges`` is given).
        edges: fixed bin edges, for comparing models and datasets.
        groups: group name -> image indices (missions or viewpoints), each reported with the
            DSP profile (μ, σ, α, β) of its complexity values.
        clusters: the bootstrap cluster label of each image (default: each image its own).
        bootstrap: interval settings; None: no intervals and no ``uncertainty`` entry.
        quality: the per-image sums of the measures beyond mIoU, in the order of
            ``confusions``; each row gets an entry per computed measure
            (:func:`~claravid.eval.analysis.quality.quality_entries`), each image its values.
        predictable: the classes the model can predict; when some class is not, every row
            also gets its mIoU over the predictable classes and its mIoU cap
            (:mod:`claravid.eval.analysis.predictable`).
        subset: a user's classes: every row also gets ``miou_classes`` over them, with its
            interval.

    Returns:
        ``{"overall", "bins", "groups", "images", "correlation", "classes", "ignore_index",
        "convention", "binning", "quality"}``, and ``"uncertainty"`` with ``bootstrap``.
    """
    confusions = np.asarray(confusions, dtype=np.int64)
    measures = _checked_inputs(paths, confusions, classes, complexity, clusters, bootstrap)
    n = len(paths)
    measure = PRIMARY_MEASURE if PRIMARY_MEASURE in measures else next(iter(measures), None)
    values = measures.get(measure) if measure else None

    report: dict[str, Any] = {
        "overall": {"num_images": n, **confusion_scores(confusions.sum(axis=0), classes)},
        "classes": list(classes),
        "ignore_index": IGNORE_INDEX,
        "convention": CONVENTION,
    }
    bin_list: list[Bin] = []
    outside: list[int] = []
    if measure is not None and values is not None:
        bin_list, outside, binning = choose_bins(values, paths, measure, bins=bins, edges=edges)
        binning["outside"] = [paths[i] for i in outside]
        report["binning"] = binning
    report["bins"], report["groups"] = _bin_and_group_rows(
        bin_list, groups or {}, confusions, classes, values, fixed=edges is not None
    )
    per_image_miou = np.array([mean_iou(c) for c in confusions])
    report["images"] = _image_rows(paths, confusions, measures, per_image_miou, quality)
    report["correlation"] = {m: correlation(v, per_image_miou) for m, v in measures.items()}
    if bootstrap is not None:
        add_intervals(report, confusions, bin_list, groups or {}, measures, per_image_miou,
                      list(paths) if clusters is None else clusters, bootstrap)  # fmt: skip
    add_quality(report, quality, classes, bin_list, groups or {},
                list(paths) if clusters is None else clusters, bootstrap)  # fmt: skip
    labels = list(paths) if clusters is None else clusters
    add_predictable(report, confusions, predictable_mask(classes, predictable), bin_list,
                    groups or {}, labels, bootstrap)  # fmt: skip
    add_predictable(report, confusions, subset_mask(classes, subset), bin_list, groups or {},
                    labels, bootstrap, key="classes")  # fmt: skip
    return report


def _bin_and_group_rows(
    bin_list: Sequence[Bin],
    groups: Mapping[str, Sequence[int]],
    confusions: np.ndarray,
    classes: Sequence[str],
    values: np.ndarray | None,
    *,
    fixed: bool,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The rows of the bins (a fixed bin's range is its edges, even when empty) and of the
    groups (each with the DSP profile of its complexity values)."""
    bin_rows = []
    for b in bin_list:
        row = _group_row(b.name, b.indices, confusions, classes, values)
        if fixed:
            row["lo"], row["hi"] = b.lo, b.hi
        bin_rows.append(row)
    group_rows = []
    for name, members in groups.items():
        row = _group_row(name, members, confusions, classes, values)
        if values is not None and len(members):
            row["profile"] = group_profile(values[list(members)])
        group_rows.append(row)
    return bin_rows, group_rows


def _checked_inputs(
    paths: Sequence[str],
    confusions: np.ndarray,
    classes: Sequence[str],
    complexity: Mapping[str, ArrayLike] | None,
    clusters: Sequence[str] | None,
    bootstrap: Bootstrap | None,
) -> dict[str, np.ndarray]:
    """The complexity values as float64 columns, after checking that the confusions, the paths
    and every column describe the same images and that the bootstrap fits in memory."""
    n = len(paths)
    if confusions.shape[0] != n or confusions.shape[1:] != (len(classes), len(classes)):
        raise ValueError(
            f"confusions {confusions.shape} do not match {n} images and {len(classes)} classes"
        )
    if n == 0:
        raise ValueError("no image to report on")
    if bootstrap is not None:  # refused before anything is computed or allocated
        bootstrap.check_memory(list(paths) if clusters is None else clusters)
    measures = {k: np.asarray(v, dtype=np.float64) for k, v in (complexity or {}).items()}
    for name, column in measures.items():
        if len(column) != n:
            raise ValueError(f"{len(column)} {name} values for {n} images")
    return measures


def _image_rows(
    paths: Sequence[str],
    confusions: np.ndarray,
    measures: Mapping[str, np.ndarray],
    per_image_miou: np.ndarray,
    quality: QualityTable | None,
) -> list[dict[str, Any]]:
    """One row per image: its path, complexities, mIoU, pixel accuracy and measures' values."""
    own = image_values(quality)
    for name, values in own.items():
        if len(values) != len(paths):
            raise ValueError(f"{len(values)} {name} values for {len(paths)} images")
    images = []
    for i, path in enumerate(paths):
        row: dict[str, Any] = {"path": path}
        row.update({m: finite_or_none(float(v[i])) for m, v in measures.items()})
        row["miou"] = finite_or_none(per_image_miou[i])
        row["pixel_acc"] = finite_or_none(pixel_accuracy(confusions[i]))
        row.update({name: finite_or_none(float(v[i])) for name, v in own.items()})
        images.append(row)
    return images


def add_quality(
    report: dict[str, Any],
    quality: QualityTable | None,
    classes: Sequence[str],
    bin_list: Sequence[Bin],
    groups: Mapping[str, Sequence[int]],
    clusters: Sequence[str],
    bootstrap: Bootstrap | None,
) -> None:
    """Add each row's measures beyond mIoU and the top-level ``quality`` entry in place.

    A row's measure draws from the generator ``<row stream>:<measure>`` (``overall``,
    ``bin:<name>``, ``group:<name>``), so its interval depends on its own images only.
    """
    report["quality"] = quality_summary(quality, "not measured")
    if quality is None:
        return
    ids = cluster_ids(clusters) if bootstrap is not None else None
    sets: list[tuple[dict[str, Any], Sequence[int], str]] = [
        (report["overall"], range(len(clusters)), "overall")
    ]
    sets += [(row, b.indices, f"bin:{b.name}")
             for b, row in zip(bin_list, report["bins"], strict=True)]  # fmt: skip
    for (name, group), row in zip(groups.items(), report["groups"], strict=True):
        sets.append((row, group, f"group:{name}"))
    for row, members, stream in sets:
        row.update(quality_entries(quality, members, classes, clusters=ids, bootstrap=bootstrap,
                                   stream=stream))  # fmt: skip


def add_intervals(
    report: dict[str, Any],
    confusions: np.ndarray,
    bin_list: Sequence[Bin],
    groups: Mapping[str, Sequence[int]],
    complexity: Mapping[str, np.ndarray],
    per_image_miou: np.ndarray,
    clusters: Sequence[str],
    settings: Bootstrap,
) -> None:
    """Add the bootstrap intervals and the ``uncertainty`` entry to ``report`` in place.

    Each set draws from its own generator (named ``overall``, ``bin:<name>``,
    ``group:<name>``, ``correlation:<measure>``), so its interval does not depend on the others.
    """
    if len(clusters) != len(confusions):
        raise ValueError(f"{len(clusters)} cluster labels for {len(confusions)} images")
    ids = cluster_ids(clusters)
    features = confusion_features(confusions)  # once, not once per bin and group

    def interval(members: ArrayLike, stream: str) -> dict[str, Any]:
        return confusion_interval(confusions, ids, members, settings, stream=stream,
                                  features=features)  # fmt: skip

    report["overall"].update(interval(np.arange(len(confusions)), "overall"))
    for b, row in zip(bin_list, report["bins"], strict=True):
        row.update(interval(b.indices, f"bin:{b.name}"))
    for (name, members), row in zip(groups.items(), report["groups"], strict=True):
        row.update(interval(members, f"group:{name}"))
    for measure, values in complexity.items():
        report["correlation"][measure].update(
            correlation_interval(
                values, per_image_miou, ids, settings, stream=f"correlation:{measure}"
            )
        )
    uncertainty = settings.describe(count_clusters(ids))
    uncertainty["warnings"] = order_warnings(report["bins"], "miou_ci", "miou")
    report["uncertainty"] = uncertainty


def bin_mious(report: Mapping[str, Any]) -> dict[str, float | None]:
    """``{bin name: mIoU}`` of a report (what a training log row carries as ``miou_bins``)."""
    return {row["name"]: row["miou"] for row in report.get("bins", [])}

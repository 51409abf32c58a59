"""The report's JSON from a per-image table: every number, then where it came from.

:func:`build_report` computes the numbers (:func:`claravid.eval.analysis.miou_bins.stratify`,
and :func:`claravid.eval.analysis.tile_bins.tile_report` with tiles) under the table's bootstrap
settings and orders them as :data:`claravid.eval.report.files.KEYS`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.miou_bins import stratify
from claravid.eval.analysis.table import EvalResult
from claravid.eval.analysis.tile_bins import tile_report
from claravid.eval.report.files import KEYS


def build_report(
    result: EvalResult,
    *,
    bins: int = 3,
    edges: Sequence[float] | None = None,
    group_by: str | None = None,
    bootstrap: Bootstrap | None = None,
    classes: Sequence[str] | None = None,
) -> dict[str, Any]:
    """The report's JSON (keys in :data:`KEYS` order); the binning goes under ``source``.

    ``bootstrap`` (default: 1000 resamples, level 0.95, seed 0, the dataset's default cluster
    unit) sets the intervals; its ``cluster`` must be a unit the images carry. ``classes``: a
    subset of the classes whose mIoU every row also gets (``miou_classes``).
    """
    settings = bootstrap or Bootstrap(cluster=result.default_cluster())
    clusters = result.cluster_labels(settings.cluster)
    numbers = stratify(
        result.paths,
        result.confusions,
        result.classes,
        result.complexity,
        bins=bins,
        edges=edges,
        groups=result.groups(group_by),
        clusters=clusters,
        bootstrap=settings,
        quality=result.quality,
        predictable=result.source.get("predictable"),
        subset=classes,
    )
    if result.tiles is not None and len(result.tiles):
        numbers["tiles"] = tile_report(
            result.tiles, result.paths, result.classes, bins=bins, edges=edges,
            clusters=clusters, bootstrap=settings,
        )  # fmt: skip
    source = dict(result.source)
    source["binning"] = {**numbers.pop("binning", {}), "group_by": group_by}
    if classes is not None:
        source["classes_subset"] = list(classes)
    numbers["palette"] = result.palette
    numbers["source"] = source
    return {key: numbers[key] for key in KEYS if key in numbers}

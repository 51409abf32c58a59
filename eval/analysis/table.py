"""The per-image table every report is made of, and joining several of them.

One row per image: its path, the name its prediction is saved under, its confusion, its
complexity values, its units (mission, viewpoint, block, sequence, folder), the sums of the
measures beyond mIoU (boundaries, calibration, its cross-view pair) and, with tiles, every
tile's delentropy and confusion. An evaluation builds it
(:func:`claravid.eval.inference.collect.collect`), a report folder stores it
(:mod:`claravid.eval.report.files`), and every number of a report is computed from it.
"""

from __future__ import annotations

import posixpath
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from claravid.eval.analysis.quality_table import QualityTable, concat_quality
from claravid.eval.analysis.tile_bins import TileTable, concat_tables
from claravid.eval.analysis.units import (
    available_units,
    default_cluster,
    group_indices,
    unit_labels,
)
from claravid.infra.cli import UsageError


@dataclass
class EvalResult:
    """One row per image: the input of every report.

    Attributes:
        paths: the RGB file of each image.
        keys: the prediction name of each image.
        confusions: int64 [N,K,K].
        complexity: measure -> float64 [N].
        attributes: unit -> one label per image: ``mission`` / ``viewpoint`` / ``block``
            (ClaraVid), ``sequence`` (UAVid), ``folder``; groups and bootstrap clusters.
        classes: the K class names.
        palette: the palette's name.
        source: where the numbers came from (written to the report as is).
        tiles: every tile's delentropy and confusion (``--tiles``), or None.
        identity: what identifies each image across reports: the real file behind its path
            (symlinks and ``..`` resolved, :func:`claravid.eval.report.files.load_result`), so
            one image reached through two spellings of the data root is one image; None: the
            normalised path.
        lineage: the ``report_id`` of every report these rows were read from, and of every
            report those were merged or re-binned from (empty for a fresh evaluation): two
            tables sharing one are one run seen twice.
        quality: the per-image sums of Boundary IoU, calibration and cross-view consistency
            (:class:`~claravid.eval.analysis.quality_table.QualityTable`); None: none measured.
    """

    paths: list[str]
    keys: list[str]
    confusions: np.ndarray
    complexity: dict[str, np.ndarray]
    attributes: dict[str, list[str]]
    classes: list[str]
    palette: str
    source: dict[str, Any] = field(default_factory=dict)
    tiles: TileTable | None = None
    identity: list[str] | None = None
    lineage: tuple[str, ...] = ()
    quality: QualityTable | None = None

    def groups(self, by: str | None) -> dict[str, list[int]] | None:
        """Image indices per unit (:func:`~claravid.eval.analysis.units.group_indices`), or None."""
        return None if by is None else group_indices(self.paths, self.attributes, by)

    def units(self) -> list[str]:
        """The cluster units these images carry (``image`` always)."""
        return available_units(self.attributes)

    def cluster_labels(self, unit: str) -> list[str]:
        """The bootstrap cluster of each image for ``unit`` (:func:`unit_labels`)."""
        return unit_labels(self.paths, self.attributes, unit)

    def image_ids(self) -> list[str]:
        """What identifies each image across reports (:attr:`identity`, else the path with
        ``.`` and ``..`` resolved)."""
        if self.identity is not None:
            return list(self.identity)
        return [posixpath.normpath(str(p).replace("\\", "/")) for p in self.paths]

    def default_cluster(self) -> str:
        """The dataset's default cluster unit, or the first fallback these images carry."""
        return default_cluster(str(self.source.get("dataset")), self.attributes)


def merge_results(results: Sequence[EvalResult], names: Sequence[str]) -> EvalResult:
    """Join the per-image tables of several runs (job-array parts, or one run to re-bin).

    Raises:
        UsageError: classes or palettes differ, or an image appears in two runs.
    """
    first = results[0]
    seen: dict[str, str] = {}
    for result, name in zip(results, names, strict=True):
        if result.classes != first.classes or result.palette != first.palette:
            raise UsageError(
                f"cannot merge {name} (palette {result.palette}, {len(result.classes)} classes) "
                f"with {names[0]} (palette {first.palette}, {len(first.classes)} classes)"
            )
        for image, path in zip(result.image_ids(), result.paths, strict=True):
            if image in seen:
                raise UsageError(
                    f"{path} (image {image}) is in both {seen[image]} and {name}: merge "
                    "disjoint runs"
                )
            seen[image] = name
    measures = [m for m in first.complexity if all(m in r.complexity for r in results)]
    attributes = [a for a in first.attributes if all(a in r.attributes for r in results)]
    order = np.argsort(np.asarray([p for r in results for p in r.paths], dtype=str), kind="stable")

    def cat(parts: list[Any]) -> list[Any]:
        flat = [x for part in parts for x in part]
        return [flat[i] for i in order]

    sources = [r.source for r in results]
    source = dict(sources[0]) if len(results) == 1 else {"kind": "merge", "parts": sources}
    source["merged_from"] = [str(n) for n in names]
    # The reports this one is made of, theirs included: a re-binning or a merge is the same
    # run as each of them (a comparison calls them not comparable), whatever its own new id.
    lineage = tuple(sorted({i for r in results for i in r.lineage}))
    source["derived_from"] = list(lineage)
    return EvalResult(
        paths=cat([r.paths for r in results]),
        keys=cat([r.keys for r in results]),
        confusions=np.concatenate([r.confusions for r in results])[order],
        complexity={m: np.concatenate([r.complexity[m] for r in results])[order] for m in measures},
        attributes={a: cat([r.attributes[a] for r in results]) for a in attributes},
        classes=first.classes,
        palette=first.palette,
        source=source,
        tiles=concat_tables([r.tiles for r in results], [len(r.paths) for r in results], order),
        identity=cat([r.image_ids() for r in results]),
        lineage=lineage,
        quality=concat_quality(
            [r.quality or QualityTable.absent("not measured") for r in results], names, order
        ),
    )

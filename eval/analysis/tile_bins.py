"""Tile-level complexity in a report (``claravid-eval --tiles T``): where the error happens.

Each image is cut into the tile grid of :mod:`claravid.dsp.tiles` in its labels' native pixels;
every tile has its own delentropy (the per-image recipe on the tile's pixels) and its own
confusion over its pixels (the image's confusion is their sum). The report's ``tiles`` entry
bins the tiles by delentropy like images (quantile bins over tiles sorted by (delentropy, path,
row, column), split as ``numpy.array_split``; or fixed edges), with each bin's mIoU from its
summed confusion and its cluster bootstrap interval (a tile is resampled with its image's
cluster), and correlates tile delentropy with the tile's own mIoU (classes with union 0 left
out; tiles without a valid pixel left out of the correlation and counted).

A tile bin's interval draws from the generator of the image bin of the same name
(``bin:<name>``), the tiles' correlation from the images' (``correlation:delent``): the same
clusters are drawn the same number of times for both, so tiles the size of the image (one per
image) give exactly the images' bins, intervals and correlation.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from claravid.eval.analysis.bins import Bin, choose_bins
from claravid.eval.analysis.bootstrap import (
    Bootstrap,
    cluster_ids,
    confusion_features,
    confusion_interval,
    correlation_interval,
)
from claravid.eval.analysis.metrics import confusion_scores, mean_iou
from claravid.eval.analysis.stats import correlation


@dataclass
class TileTable:
    """One row per tile of every image of an :class:`~claravid.eval.analysis.table.EvalResult`.

    Attributes:
        size: the tile size T in pixels.
        image: int64 [M], the row of the tile's image in the result.
        row, col: int64 [M], the tile's place in its image's grid.
        delent: float64 [M], the tile's delentropy.
        confusions: int64 [M, K, K], the confusion over the tile's pixels.
    """

    size: int
    image: np.ndarray
    row: np.ndarray
    col: np.ndarray
    delent: np.ndarray
    confusions: np.ndarray

    @classmethod
    def from_images(
        cls, size: int, per_image: Sequence[tuple[np.ndarray, np.ndarray]], num_classes: int
    ) -> TileTable:
        """From each image's (delentropy [R, C], confusions [R, C, K, K]), in result order."""
        image, row, col, delent, confusions = [], [], [], [], []
        for index, (values, conf) in enumerate(per_image):
            rows, cols = values.shape
            r, c = np.divmod(np.arange(rows * cols), cols)
            image.append(np.full(rows * cols, index, dtype=np.int64))
            row.append(r)
            col.append(c)
            delent.append(values.reshape(-1))
            confusions.append(conf.reshape(rows * cols, num_classes, num_classes))
        if not image:
            empty = np.zeros(0, dtype=np.int64)
            k = num_classes
            return cls(size, empty, empty, empty, np.zeros(0), np.zeros((0, k, k), np.int64))
        return cls(
            size,
            np.concatenate(image),
            np.concatenate(row).astype(np.int64),
            np.concatenate(col).astype(np.int64),
            np.concatenate(delent).astype(np.float64),
            np.concatenate(confusions).astype(np.int64),
        )

    def __len__(self) -> int:
        return len(self.image)

    def grid(self, index: int) -> np.ndarray:
        """The delentropy of image ``index``'s tiles as its grid [rows, cols]."""
        mine = np.flatnonzero(self.image == index)
        out = np.full((int(self.row[mine].max()) + 1, int(self.col[mine].max()) + 1), np.nan)
        out[self.row[mine], self.col[mine]] = self.delent[mine]
        return out


def concat_tables(
    tables: Sequence[TileTable | None], num_images: Sequence[int], image_order: np.ndarray
) -> TileTable | None:
    """Join the tile tables of merged results (None unless all have tiles of one size).

    Args:
        tables: each result's tiles.
        num_images: each result's number of images.
        image_order: the merge's permutation over the concatenated images (``order[new] = old``).
    """
    present = [t for t in tables if t is not None]
    if not tables or len(present) != len(tables) or len({t.size for t in present}) != 1:
        return None
    new_index = np.empty(len(image_order), dtype=np.int64)
    new_index[np.asarray(image_order)] = np.arange(len(image_order))
    offsets = np.concatenate([[0], np.cumsum(num_images)[:-1]]).astype(np.int64)
    image = np.concatenate([new_index[t.image + o] for t, o in zip(present, offsets, strict=True)])
    row, col = np.concatenate([t.row for t in present]), np.concatenate([t.col for t in present])
    order = np.lexsort((col, row, image))  # tiles in image order, then row-major
    return TileTable(
        present[0].size,
        image[order],
        row[order],
        col[order],
        np.concatenate([t.delent for t in present])[order],
        np.concatenate([t.confusions for t in present])[order],
    )


def tile_bins(
    table: TileTable, paths: Sequence[str], bins: int, edges: Sequence[float] | None
) -> tuple[list[Bin], list[int], dict[str, Any]]:
    """The tiles' bins, the tiles outside fixed edges, and the ``binning`` entry.

    Quantile bins: tiles sorted by (delentropy, image path, row, column), split as
    ``numpy.array_split``; fixed edges: as images (:func:`claravid.eval.analysis.bins.fixed_bins`).
    """
    path_rank = np.argsort(np.argsort(np.asarray(paths, dtype=str), kind="stable"), kind="stable")
    order = np.lexsort((table.col, table.row, path_rank[table.image], table.delent))
    return choose_bins(table.delent, paths, "delent", bins=bins, edges=edges, order=order,
                       what="tiles")  # fmt: skip


def _warn_outside(delent: np.ndarray, outside: int) -> None:
    """Say when fixed edges leave tiles in no bin, with the tiles' delentropy range (the
    report only counts them; images outside are warned the same way)."""
    if not outside:
        return
    finite = delent[np.isfinite(delent)]
    span = f"{finite.min():.2f}..{finite.max():.2f}" if finite.size else "n/a"
    every = "no tile is in a bin" if outside == len(delent) else "they are in no bin"
    warnings.warn(
        f"{outside} of {len(delent)} tile(s) fall outside --edges (delentropy of the tiles: "
        f"{span}): {every}; a tile has fewer pixels than its image and measures lower, so "
        "give edges over the tiles' range",
        UserWarning,
        stacklevel=4,
    )


def tile_report(
    table: TileTable,
    paths: Sequence[str],
    classes: Sequence[str],
    *,
    bins: int = 3,
    edges: Sequence[float] | None = None,
    clusters: Sequence[str] | None = None,
    bootstrap: Bootstrap | None = None,
) -> dict[str, Any]:
    """The report's ``tiles`` entry.

    Args:
        table: the tiles.
        paths: the images' paths (tile ``image`` indexes them).
        classes: the K class names.
        bins, edges: as for images.
        clusters: each image's bootstrap cluster label; a tile goes with its image's cluster.
        bootstrap: interval settings (None: no intervals).

    Returns:
        ``{"size", "num_tiles", "num_without_labels", "binning", "bins", "correlation"}``.
    """
    labels = list(paths) if clusters is None else list(clusters)
    if bootstrap is not None:  # tiles draw their images' clusters
        bootstrap.check_memory(labels)
    bin_list, outside, binning = tile_bins(table, paths, bins, edges)
    ids = None
    if bootstrap is not None:
        ids = cluster_ids(labels)[table.image]
        features = confusion_features(table.confusions)
    rows = []
    for b in bin_list:
        members = list(b.indices)
        conf = table.confusions[members].sum(axis=0)
        row: dict[str, Any] = {"name": b.name, "lo": b.lo, "hi": b.hi, "num_tiles": len(members)}
        row.update(confusion_scores(conf, classes))
        if bootstrap is not None and ids is not None:
            interval = confusion_interval(
                table.confusions, ids, members, bootstrap, stream=f"bin:{b.name}",
                features=features,
            )  # fmt: skip
            row.update(interval)
        rows.append(row)
    tile_miou = np.array([mean_iou(c) for c in table.confusions], dtype=np.float64)
    without_labels = int((table.confusions.sum(axis=(1, 2)) == 0).sum())
    corr = correlation(table.delent, tile_miou)
    if bootstrap is not None and ids is not None:
        corr.update(correlation_interval(table.delent, tile_miou, ids, bootstrap,
                                         stream="correlation:delent"))  # fmt: skip
    if edges is not None:
        binning["outside"] = len(outside)
        _warn_outside(table.delent, len(outside))
    return {
        "size": table.size,
        "num_tiles": len(table),
        "num_without_labels": without_labels,
        "binning": binning,
        "bins": rows,
        "correlation": {"delent": corr},
    }

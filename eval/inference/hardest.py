"""The hardest images of an evaluation: kept while the model runs, drawn in the report.

:class:`Hardest` keeps a small copy of the k lowest-mIoU predictions as they stream by (a
heap, so memory stays k thumbnails on a 17k-image run); :func:`hardest_items` gathers image,
ground truth, prediction (and, with tiles, the tile delentropy and the error pixels) for
``hardest.png`` and ``tiles.png`` (:mod:`claravid.eval.report.plots`).
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from claravid.data.ignore import IGNORE_INDEX
from claravid.data.palette_fold import PaletteFold
from claravid.eval.analysis.metrics import mean_iou
from claravid.eval.analysis.table import EvalResult
from claravid.eval.inputs.datasets import EvalData
from claravid.eval.inputs.label_maps import prediction_file, read_scored

THUMB = 512  # longest side of a hardest-image panel


def thumbnail(array: np.ndarray, nearest: bool) -> np.ndarray:
    """A copy at most :data:`THUMB` pixels on its longest side (label maps: nearest)."""
    h, w = array.shape[:2]
    f = THUMB / max(h, w)
    if f >= 1:
        return np.ascontiguousarray(array)
    size = (max(1, round(w * f)), max(1, round(h * f)))
    return cv2.resize(array, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


@dataclass
class Hardest:
    """The k images of lowest mIoU seen so far, with a small copy of their prediction."""

    k: int
    heap: list[tuple[float, int, np.ndarray]] = field(default_factory=list)

    def offer(self, index: int, miou: float, prediction: torch.Tensor) -> None:
        """Keep this image if it is among the k hardest so far (ties: the lower index)."""
        if self.k <= 0 or not np.isfinite(miou):
            return
        # A min-heap on (-mIoU, -index): its root is the easiest kept image, evicted first.
        rank = (-miou, -index)
        if len(self.heap) < self.k or rank > self.heap[0][:2]:
            item = (-miou, -index, thumbnail(prediction.to("cpu", torch.uint8).numpy(), True))
            if len(self.heap) < self.k:
                heapq.heappush(self.heap, item)
            else:
                heapq.heapreplace(self.heap, item)


def hardest_items(
    result: EvalResult,
    data: EvalData | None,
    k: int,
    kept: dict[int, np.ndarray],
    prediction_dirs: Sequence[str | Path],
    fold: PaletteFold | None = None,
) -> list[dict[str, Any]]:
    """Image, ground truth and prediction of the k lowest-mIoU images, as small arrays.

    A prediction comes from ``kept`` (the model's run) or from a folder of saved label maps;
    images without one are left out. ``fold``: the folders hold a fine model's label maps,
    scored through the palette (:func:`~claravid.eval.inputs.label_maps.read_scored`). With
    tiles, an item also has its tiles' delentropy grid (``tiles``) and its error pixels
    (``errors``, :func:`error_map`).
    """
    if data is None or k <= 0:
        return []
    mious = np.array([mean_iou(c) for c in result.confusions])
    order = [i for i in np.argsort(np.where(np.isnan(mious), np.inf, mious), kind="stable")
             if np.isfinite(mious[i])][:k]  # fmt: skip
    index_of = {key: i for i, key in enumerate(data.keys)}
    items = []
    for pos in order:
        key = result.keys[pos]
        pred = kept.get(int(pos))
        sample = data.dataset[index_of[key]]
        mask = np.asarray(sample["mask"], dtype=np.uint8)
        if pred is None:
            for folder in prediction_dirs:
                file = prediction_file(folder, key)
                if file.is_file():
                    pred = thumbnail(read_scored(file, mask.shape, len(result.classes), fold), True)
                    break
        if pred is None:
            continue
        image = sample["image"].permute(1, 2, 0).numpy()
        small_mask = thumbnail(mask, nearest=True)
        item = {
            "image": thumbnail(image, nearest=False),
            "mask": small_mask,
            "prediction": pred,
            "title": f"{key}\nmIoU {mious[pos]:.3f}  delent "
            f"{result.complexity.get('delent', [np.nan] * len(mious))[pos]:.2f}",
        }  # fmt: skip
        if result.tiles is not None and pred.shape == small_mask.shape:
            item["tiles"] = result.tiles.grid(int(pos))
            item["errors"] = error_map(pred, small_mask)
        items.append(item)
    return items


def error_map(prediction: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """uint8 [H, W]: 1 where the prediction is wrong, 0 where right, 2 where ignored (255)."""
    out = (np.asarray(prediction) != np.asarray(mask)).astype(np.uint8)
    out[np.asarray(mask) == IGNORE_INDEX] = 2
    return out

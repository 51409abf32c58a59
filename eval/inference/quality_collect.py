"""The measures beyond mIoU in a collection: what a label map's thread measures, the table the
gathered rows make, and the sheet's pairs (:func:`claravid.eval.inference.collect.collect`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from claravid.data.palette_fold import PaletteFold
from claravid.eval.analysis.quality_table import (
    BOUNDARY,
    CALIBRATION,
    CONSISTENCY,
    PairTable,
    QualityTable,
)
from claravid.eval.inference.hardest import thumbnail
from claravid.eval.inference.image_sums import image_measures
from claravid.eval.inference.pair_stream import PairKeeper
from claravid.eval.inference.quality_plan import QualityPlan
from claravid.eval.inputs.datasets import EvalData
from claravid.eval.inputs.label_maps import prediction_file, read_scored
from claravid.eval.inputs.pass_frames import PairResult, PassFrames, measure_pair


def pair_item(frames: PassFrames, item: dict[str, Any]) -> dict[str, Any]:
    """A kept pair with the thumbnails of its two frames' images, for ``hardest.png``."""

    def rgb(key: str) -> np.ndarray:
        return thumbnail(frames.image(key).permute(1, 2, 0).numpy(), nearest=False)

    stem = item["next"].rsplit("/", 1)[-1]
    title = (f"{item['key']}\nconsistency {item['consistency']:.3f} with {stem} (kept pixels: "
             "green agree, red disagree)")  # fmt: skip
    return {**item, "image": rgb(item["key"]), "next_image": rgb(item["next"]), "title": title}


def label_map_measure(
    data: EvalData,
    predictions: str | Path | None,
    plan: QualityPlan,
    frames: PassFrames | None,
    keeper: PairKeeper,
    fold: PaletteFold | None = None,
) -> Any:
    """What a label map's reading thread measures beside the confusion: the boundary sums, and
    the image's pair with the next frame (whose label map is read from the same folder),
    offered to ``keeper`` there (the full-size maps go no further)."""
    measures = plan.image_measures()
    k = data.palette.num_classes
    if not measures.boundary and frames is None:
        return None
    folder = Path(str(predictions))

    def pred_s(key: str) -> np.ndarray | str:
        assert frames is not None  # pairs are measured only with a pass's frames
        file = prediction_file(folder, key)
        if not file.is_file():
            return f"no label map of the next frame ({file})"
        return read_scored(file, frames.mask(key).shape, k, fold)

    def measure(index: int, ids: np.ndarray, mask: np.ndarray) -> tuple[Any, Any]:
        boundary, _ = image_measures(ids, mask, k, measures)
        if frames is None:
            return boundary, None
        key = data.keys[index]
        after = frames.next_of(key)
        other = pred_s(after) if after else ""
        result = measure_pair(frames, key, ids, mask, lambda _key: other, k,
                              keep_geometry=keeper.k > 0)  # fmt: skip
        # A pair with geometry was measured, so the next frame had a label map.
        if result.geometry is not None and after and isinstance(other, np.ndarray):
            keeper.offer(index, key, result, (ids, mask, other, frames.mask(after)))
        result.geometry = None  # full-size depth maps are not kept past the sheet
        return boundary, result

    return measure


def quality_table(plan: QualityPlan, rows: list[tuple[Any, ...]], k: int) -> QualityTable:
    """The gathered rows' measures beyond mIoU as a table (status and reasons from ``plan``)."""
    boundary = calibration = pairs = None
    if plan.on(BOUNDARY):
        boundary = np.stack([r[3][0] for r in rows]).astype(np.int64)
    if plan.on(CALIBRATION):
        calibration = np.stack([r[3][1] for r in rows]).astype(np.float64)
    if plan.on(CONSISTENCY):
        results: list[PairResult] = [r[4] for r in rows]
        pairs = PairTable([p.next for p in results], [p.status for p in results],
                          [p.reason for p in results],
                          np.stack([p.sums for p in results]))  # fmt: skip
    return QualityTable(dict(plan.status), dict(plan.reasons), boundary, calibration, pairs,
                        {n: dict(v) for n, v in plan.settings.items()})  # fmt: skip

"""Run a model over a dataset: one confusion matrix per image (the input of every report), and
with it the image's boundary and calibration sums when asked for.

Training validates through this function and ``claravid-eval`` reports from it, so windows,
confusions and mIoU have one implementation. Under DDP each rank passes its own ``indices``
and the per-image results are gathered afterwards (``claravid.infra.distributed``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Subset
from tqdm.auto import tqdm

from claravid.data.palette_fold import PaletteFold
from claravid.eval.inference.background import Background
from claravid.eval.inference.image_sums import (
    ImageMeasures,
    image_measures,
    predict_with_confidence,
)
from claravid.eval.inference.windows import Model, WindowConfig
from claravid.eval.inputs.label_maps import image_key
from claravid.eval.measures.confusion import image_confusion


@dataclass
class ImageScore:
    """One image's result: where it came from, its confusion (int64 [K,K]); with a tile size,
    the confusion of each tile (int64 [rows, cols, K, K], summing to ``confusion``); when asked
    for, its boundary sums (int64 [2, K]: intersections, unions) and calibration sums (float64
    [3, B]: count, confidence sum, correct)."""

    path: str
    key: str
    confusion: np.ndarray
    tiles: np.ndarray | None = None
    boundary: np.ndarray | None = None
    calibration: np.ndarray | None = None


def sample_key(sample: dict[str, Any]) -> str:
    """The name a sample's prediction is saved under: its ``key``, else
    :func:`claravid.eval.inputs.label_maps.image_key` of its path (the stem)."""
    key = sample.get("key")
    return str(key) if key else image_key(str(sample["path"]))


def evaluate_model(
    model: Model,
    dataset: Dataset,
    num_classes: int,
    config: WindowConfig | None = None,
    *,
    device: torch.device | str = "cpu",
    indices: Sequence[int] | None = None,
    num_workers: int = 0,
    tile_size: int | None = None,
    progress: bool = False,
    on_score: Callable[[dict[str, Any], torch.Tensor, ImageScore], None] | None = None,
    measures: ImageMeasures | None = None,
    background: Background | None = None,
    fold: PaletteFold | None = None,
) -> list[ImageScore]:
    """Predict every image of ``dataset`` with sliding windows and count its confusion.

    Args:
        model: a module already on ``device`` (in eval mode) or any callable (ONNX Runtime).
        dataset: samples with a uint8 (or normalised float) ``image`` [3,H,W], ``mask`` [H,W]
            and ``path`` (e.g. ``ClaraVidSegmentation(..., transforms=eval_transforms())``).
        num_classes: K, the palette's classes.
        config: windows, stride, scale, batch size, precision, normalisation (unset: the
            model's natural window and own statistics, `WindowConfig.for_model`).
        device: where images go and confusions are counted.
        indices: evaluate only these dataset indices (a rank's shard).
        num_workers: DataLoader workers decoding the next images while the model runs.
        tile_size: also count each tile's confusion (:mod:`claravid.eval.analysis.tile_bins`).
        progress: show a progress bar.
        on_score: called with each sample, its predicted ids [H,W] and its `ImageScore` (to
            save the prediction, keep the hardest images', or pair it with the next frame).
        measures: also each image's Boundary IoU and calibration sums
            (:class:`~claravid.eval.inference.image_sums.ImageMeasures`).
        background: where those run, beside the next image's prediction (default: at once).
        fold: a fine model scored through the palette of ``num_classes`` classes: the argmax
            (and confidence) of its summed probabilities
            (:func:`~claravid.eval.inference.image_sums.folded_scores`).

    Returns:
        One `ImageScore` per image, in dataset order.
    """
    # The window and statistics the config leaves unset are the model's; checked once here.
    config = (config or WindowConfig()).for_model(model)
    measures = measures or ImageMeasures()
    background = background or Background(0)
    device = torch.device(device)
    subset = Subset(dataset, list(indices)) if indices is not None else dataset
    loader = DataLoader(subset, batch_size=None, num_workers=num_workers)
    results, pending = [], []
    # A map-style dataset has a length; torch's Dataset type does not declare one.
    total = len(subset)  # type: ignore[arg-type]
    for sample in tqdm(loader, total=total, desc="evaluate", unit="img", disable=not progress):
        if "mask" not in sample:
            raise ValueError(f"{sample['path']} has no ground truth: evaluation needs labels")
        prediction, scores = predict_with_confidence(
            model, sample["image"].to(device), config, measures.calibration, fold
        )
        confidence: torch.Tensor | np.ndarray | None = scores
        if scores is not None and not isinstance(model, torch.nn.Module):
            confidence = scores.cpu().numpy()  # ONNX Runtime's scores, on the CPU: numpy counts
        target = torch.as_tensor(sample["mask"]).to(device)
        if prediction.device.type == "cpu" and num_classes <= 255:
            # Byte ids take metrics' fast CPU path (an int64 map would be checked and cast).
            prediction = prediction.to(torch.uint8)
        conf, tiles = image_confusion(prediction, target, num_classes, tile_size)
        score = ImageScore(str(sample["path"]), sample_key(sample), conf, tiles)
        if measures.boundary or measures.calibration:
            ids = prediction.to(torch.uint8) if num_classes <= 255 else prediction
            pending.append((score, background.submit(image_measures, ids, target, num_classes,
                                                     measures, confidence)))  # fmt: skip
        results.append(score)
        if on_score is not None:
            on_score(sample, prediction, score)
    for score, job in pending:
        score.boundary, score.calibration = job.result()
    return results

"""Validation during training, through the evaluation core (``eval/``): sliding windows,
per-image confusions, mIoU, per-class IoU, mIoU per delentropy bin of the val images, and beside
them mBoundaryIoU (overall and per bin) from each image's boundary sums.

The delentropy of each val image is computed once per run (read from the DSP cache when the
files were profiled before), each rank measuring its own shard. Under DDP each rank evaluates
every W-th image and the per-image confusions are gathered in order; every rank gets the same
row, rank 0 logs it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from claravid.eval.analysis.miou_bins import bin_mious, stratify
from claravid.eval.analysis.quality_table import QualityTable
from claravid.eval.inference.image_sums import ImageMeasures
from claravid.eval.inference.run_model import evaluate_model
from claravid.eval.inference.windows import WindowConfig
from claravid.infra.distributed import gather_in_order, shard_indices
from claravid.train.data import SegmentationSplit, image_paths
from claravid.train.sampler import sharded_delentropy


class Validator:
    """Scores a model on the val set; ``validator(model)`` → a metrics row (without ``step``).

    Args:
        dataset: the val set with evaluation transforms.
        classes: the palette's class names (K).
        window: sliding-window settings.
        bins: delentropy quantile bins.
        limit: evaluate this many images only, spread evenly over the set (None: all).
        device: where the model runs.
    """

    def __init__(
        self,
        dataset: SegmentationSplit,
        classes: list[str],
        window: WindowConfig,
        bins: int = 3,
        limit: int | None = None,
        device: torch.device | str = "cpu",
    ) -> None:
        n = len(dataset)
        self.dataset, self.classes, self.window, self.bins = dataset, classes, window, bins
        self.device = torch.device(device)
        if limit is not None and limit < n:
            self.indices = sorted({int(i) for i in np.linspace(0, n - 1, limit).round()})
        else:
            self.indices = list(range(n))
        if len(self.indices) < bins:  # fail before training, not at the first validation
            raise ValueError(
                f"the val set has {len(self.indices)} image(s), fewer than val.bins={bins} "
                "delentropy bins: lower val.bins or validate on more images"
            )
        self.paths = [image_paths(dataset)[i] for i in self.indices]
        # An unreadable image has no complexity (NaN); its evaluation will name the file.
        self.delent = sharded_delentropy(self.paths)

    def __call__(self, model: nn.Module, progress: bool = False) -> dict[str, Any]:
        was_training = model.training
        model.eval()
        mine = shard_indices(len(self.indices))
        try:
            scores = evaluate_model(
                model,
                self.dataset,
                len(self.classes),
                self.window,
                device=self.device,
                indices=[self.indices[i] for i in mine],
                progress=progress,
                measures=ImageMeasures(boundary=True),
            )
        finally:
            model.train(was_training)
        rows = gather_in_order([(s.confusion, s.boundary) for s in scores], mine)
        boundaries = []
        for _, sums in rows:
            if sums is None:  # asked for with ImageMeasures(boundary=True)
                raise RuntimeError("evaluate_model returned an image without its boundary sums")
            boundaries.append(sums)
        quality = QualityTable({"boundary_iou": "computed"}, boundary=np.stack(boundaries))
        report = stratify(self.paths, np.stack([c for c, _ in rows]), self.classes,
                          {"delent": self.delent}, bins=self.bins, quality=quality)  # fmt: skip
        overall = report["overall"]
        return {
            "miou": overall["miou"],
            "pixel_acc": overall["pixel_acc"],
            "per_class_iou": overall["per_class_iou"],
            "miou_bins": bin_mious(report),
            "boundary_miou": overall["boundary_iou"]["miou"],
            "boundary_miou_bins": {r["name"]: r["boundary_iou"]["miou"] for r in report["bins"]},
        }

"""Evaluation: sliding-window inference, per-image confusion, mIoU per complexity bin, reports.

The core that training validates through::

    from claravid.eval import WindowConfig, evaluate_model, stratify

    scores = evaluate_model(model, val_dataset, num_classes=8, config=WindowConfig(scale=0.5))
    report = stratify([s.path for s in scores], np.stack([s.confusion for s in scores]),
                      classes, {"delent": values}, bins=3)

The product on top (``claravid-eval``, ``claravid-predict``; see :mod:`claravid.eval.cli`)::

    from claravid.eval.data import open_data            # ClaraVid / UAVid / folder: keys, labels
    from claravid.eval.collect import collect
    from claravid.eval.report import build_report, write_outputs

    data = open_data("/data/claravid", split="val", palette="uavid")
    collected = collect(data, predictions="preds/")    # or model=eval.sources.load_source(...)
    report = build_report(collected.result, bins=3)
    write_outputs("report/", report, collected.result)

Modules: ``data`` (what is evaluated), ``units`` (groups and bootstrap clusters),
``sources`` (checkpoint / ONNX), ``label_maps`` (label maps on disk, image keys),
``complexity`` (delentropy beside inference), ``collect`` (one evaluation's per-image table,
sharded under torchrun), ``tiles`` (tile-level complexity), ``hardest`` (the hardest images),
``report`` (JSON, confusions, merge, the report folder), ``bootstrap`` (intervals),
``markdown``, ``plots``, ``compare``, ``scores`` (any per-image metric), ``cli``, ``predict``.
"""

from claravid.eval.bins import Bin, bin_names, fixed_bins, parse_edges, quantile_bins
from claravid.eval.evaluate import ImageScore, evaluate_model, sample_key
from claravid.eval.metrics import (
    CONVENTION,
    IGNORE_INDEX,
    confusion_matrix,
    iou_per_class,
    mean_iou,
    pixel_accuracy,
    scores,
)
from claravid.eval.stratify import bin_mious, correlation, stratify
from claravid.eval.windows import WindowConfig, predict_labels, sliding_window_logits, window_starts

__all__ = [
    "CONVENTION",
    "IGNORE_INDEX",
    "Bin",
    "ImageScore",
    "WindowConfig",
    "bin_mious",
    "bin_names",
    "confusion_matrix",
    "correlation",
    "evaluate_model",
    "fixed_bins",
    "iou_per_class",
    "mean_iou",
    "parse_edges",
    "pixel_accuracy",
    "predict_labels",
    "quantile_bins",
    "sample_key",
    "scores",
    "sliding_window_logits",
    "stratify",
    "window_starts",
]

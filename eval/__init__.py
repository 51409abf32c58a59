"""Evaluation: mIoU per complexity bin from any model, with intervals, tiles and comparisons.

Three layers, imports pointing one way (inference → analysis ← report):

- :mod:`claravid.eval.inference` (torch): the data an evaluation reads, model and label-map
  sources, sliding windows, the per-image sums (the confusion of an image and of its tiles,
  Boundary IoU, calibration bins) and the per-pair cross-view sums, and the per-image
  collection with its background complexity job;
- :mod:`claravid.eval.analysis` (numpy only, no torch, no files): the per-image table and its
  merging, metrics, bins, units, the cluster bootstrap, mIoU per bin, tiles' bins, paired
  comparisons and any per-image metric;
- :mod:`claravid.eval.report`: the report's JSON and its folder (``report.json``,
  ``confusions.npz``, ``report.md``, plots) and the comparison folder.

The console scripts sit beside them: ``claravid-eval`` (:mod:`claravid.eval.cli`),
``claravid-predict`` (:mod:`claravid.eval.predict`), ``claravid-export``
(:mod:`claravid.eval.export_cli`).

The core that training validates through::

    from claravid.eval import WindowConfig, evaluate_model, stratify

    scores = evaluate_model(model, val_dataset, num_classes=8, config=WindowConfig(scale=0.5))
    report = stratify([s.path for s in scores], np.stack([s.confusion for s in scores]),
                      classes, {"delent": values}, bins=3)

What ``claravid-eval`` does, in one call (:mod:`claravid.eval.run`, :mod:`claravid.eval.reports`)::

    from claravid.eval import DataChoice, ReportSettings, compare, evaluate, merge

    done = evaluate("report/", checkpoint="best.pt", data=DataChoice(split="val"))
    merge(["part0/", "part1/"], "all/", ReportSettings(edges=[4, 4.5, 5]))
    print(compare(["all/", "other/"], "cmp/"))

and step by step::

    from claravid.eval import build_report, collect, open_data, write_outputs

    data = open_data("/data/claravid", split="val", palette="uavid")
    collected = collect(data, predictions="preds/")    # or model=load_source(checkpoint=...)
    report = build_report(collected.result, bins=3)
    write_outputs("report/", report, collected.result)

Beyond mIoU, each measure is a sum per image (or per pair), like a confusion matrix::

    from claravid.eval import boundary_iou, calibration_bins, cross_view

    inter, union = boundary_iou(pred, gt, num_classes=8)            # int64 [K] each
    count, conf_sum, correct = calibration_bins(probs, gt)          # 15 bins
    sums = cross_view(depth_t, depth_s, c2w_t, c2w_s, K, pred_t, pred_s, gt_t, gt_s,
                      dynamic_t, dynamic_s, num_classes=8)          # a CrossViewSums

Every name below is imported on first use, so ``import claravid.eval`` (and the analysis and
report layers) never loads torch unless a torch-side name is asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

# Public name -> (module, attribute), imported on first access (PEP 562).
_LAZY: dict[str, tuple[str, str]] = {
    # analysis (numpy)
    "CONVENTION": ("claravid.eval.analysis.metrics", "CONVENTION"),
    "IGNORE_INDEX": ("claravid.eval.analysis.metrics", "IGNORE_INDEX"),
    "iou_per_class": ("claravid.eval.analysis.metrics", "iou_per_class"),
    "mean_iou": ("claravid.eval.analysis.metrics", "mean_iou"),
    "pixel_accuracy": ("claravid.eval.analysis.metrics", "pixel_accuracy"),
    "calibration_errors": ("claravid.eval.analysis.calibration", "calibration_errors"),
    "confusion_scores": ("claravid.eval.analysis.metrics", "confusion_scores"),
    "Bin": ("claravid.eval.analysis.bins", "Bin"),
    "bin_names": ("claravid.eval.analysis.bins", "bin_names"),
    "fixed_bins": ("claravid.eval.analysis.bins", "fixed_bins"),
    "parse_edges": ("claravid.eval.analysis.bins", "parse_edges"),
    "quantile_bins": ("claravid.eval.analysis.bins", "quantile_bins"),
    "Bootstrap": ("claravid.eval.analysis.bootstrap", "Bootstrap"),
    "correlation": ("claravid.eval.analysis.stats", "correlation"),
    "stratify": ("claravid.eval.analysis.miou_bins", "stratify"),
    "bin_mious": ("claravid.eval.analysis.miou_bins", "bin_mious"),
    "EvalResult": ("claravid.eval.analysis.table", "EvalResult"),
    "QualityTable": ("claravid.eval.analysis.quality_table", "QualityTable"),
    "PairTable": ("claravid.eval.analysis.quality_table", "PairTable"),
    "merge_results": ("claravid.eval.analysis.table", "merge_results"),
    # report (numpy, files, matplotlib)
    "build_report": ("claravid.eval.report.build", "build_report"),
    "load_result": ("claravid.eval.report.files", "load_result"),
    "write_outputs": ("claravid.eval.report.folder", "write_outputs"),
    "compare_reports": ("claravid.eval.report.compare", "compare_reports"),
    # inference (torch)
    "WindowConfig": ("claravid.eval.inference.windows", "WindowConfig"),
    "predict_labels": ("claravid.eval.inference.windows", "predict_labels"),
    "sliding_window_logits": ("claravid.eval.inference.windows", "sliding_window_logits"),
    "window_starts": ("claravid.eval.inference.windows", "window_starts"),
    "confusion_matrix": ("claravid.eval.inference.confusion", "confusion_matrix"),
    "boundary_iou": ("claravid.eval.inference.boundary", "boundary_iou"),
    "calibration_bins": ("claravid.eval.inference.calibration", "calibration_bins"),
    "cross_view": ("claravid.eval.inference.cross_view", "cross_view"),
    "CrossViewSums": ("claravid.eval.inference.cross_view", "CrossViewSums"),
    "ImageScore": ("claravid.eval.inference.run_model", "ImageScore"),
    "ImageMeasures": ("claravid.eval.inference.image_measures", "ImageMeasures"),
    "evaluate_model": ("claravid.eval.inference.run_model", "evaluate_model"),
    "sample_key": ("claravid.eval.inference.run_model", "sample_key"),
    "open_data": ("claravid.eval.inference.data", "open_data"),
    "load_source": ("claravid.eval.inference.sources", "load_source"),
    "collect": ("claravid.eval.inference.collect", "collect"),
    "CollectSettings": ("claravid.eval.inference.collect", "CollectSettings"),
    # runs: what each claravid-eval mode does, in one call
    "evaluate": ("claravid.eval.run", "evaluate"),
    "score_metrics": ("claravid.eval.run", "score_metrics"),
    "merge": ("claravid.eval.reports", "merge"),
    "compare": ("claravid.eval.reports", "compare"),
    "DataChoice": ("claravid.eval.settings", "DataChoice"),
    "InferenceSettings": ("claravid.eval.settings", "InferenceSettings"),
    "ReportSettings": ("claravid.eval.settings", "ReportSettings"),
    "Evaluation": ("claravid.eval.settings", "Evaluation"),
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    target = _LAZY.get(name)
    if target is None:
        raise AttributeError(f"module 'claravid.eval' has no attribute {name!r}")
    return getattr(importlib.import_module(target[0]), target[1])


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])

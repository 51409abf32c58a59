"""Evaluation: mIoU per complexity bin from any model, with intervals, tiles and comparisons.

Rooms, imports pointing one way (inputs, measures → inference → analysis ← report):

- :mod:`claravid.eval.inputs`: what an evaluation reads (the images and labels of ClaraVid,
  UAVid or a folder, saved label maps, per-image metric CSVs, frame pairs and their geometry);
- :mod:`claravid.eval.measures`: the per-image sums (the confusion of an image and of its tiles,
  Boundary IoU, calibration bins) and the per-pair cross-view sums;
- :mod:`claravid.eval.inference` (torch): model and label-map sources, sliding windows, running
  the model, and the per-image collection with its background complexity job;
- :mod:`claravid.eval.analysis` (numpy only, no torch, no files): the per-image table and its
  merging, metrics, bins, units, the cluster bootstrap, mIoU per bin, tiles' bins, paired
  comparisons and any per-image metric;
- :mod:`claravid.eval.report`: the report's JSON and its folder (``report.json``,
  ``confusions.npz``, ``report.md``, plots) and the comparison folder.

The console scripts live in :mod:`claravid.eval.cli`: ``claravid-eval``
(:mod:`claravid.eval.cli.evaluate`),
``claravid-predict`` (:mod:`claravid.eval.cli.predict`), ``claravid-export``
(:mod:`claravid.eval.cli.export`).

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

from typing import TYPE_CHECKING

from claravid.infra.lazy import lazy_exports

__all__ = [
    "CONVENTION",
    "IGNORE_INDEX",
    "Bin",
    "Bootstrap",
    "CollectSettings",
    "CrossViewSums",
    "DataChoice",
    "EvalResult",
    "Evaluation",
    "ImageMeasures",
    "ImageScore",
    "InferenceSettings",
    "PairTable",
    "QualityTable",
    "ReportSettings",
    "TTAConfig",
    "WindowConfig",
    "bin_mious",
    "bin_names",
    "boundary_iou",
    "build_report",
    "calibration_bins",
    "calibration_errors",
    "class_probabilities",
    "collect",
    "compare",
    "compare_reports",
    "confusion_matrix",
    "confusion_scores",
    "correlation",
    "cross_view",
    "evaluate",
    "evaluate_model",
    "fixed_bins",
    "iou_per_class",
    "load_result",
    "load_source",
    "mean_iou",
    "merge",
    "merge_results",
    "open_data",
    "parse_edges",
    "pixel_accuracy",
    "predict_labels",
    "quantile_bins",
    "sample_key",
    "score_metrics",
    "sliding_window_logits",
    "stratify",
    "window_starts",
    "write_outputs",
]

if TYPE_CHECKING:
    from claravid.eval.analysis.bins import Bin, bin_names, fixed_bins, parse_edges, quantile_bins
    from claravid.eval.analysis.bootstrap import Bootstrap
    from claravid.eval.analysis.calibration import calibration_errors
    from claravid.eval.analysis.metrics import (
        CONVENTION,
        IGNORE_INDEX,
        confusion_scores,
        iou_per_class,
        mean_iou,
        pixel_accuracy,
    )
    from claravid.eval.analysis.miou_bins import bin_mious, stratify
    from claravid.eval.analysis.quality_table import PairTable, QualityTable
    from claravid.eval.analysis.stats import correlation
    from claravid.eval.analysis.table import EvalResult, merge_results
    from claravid.eval.inference.augment import TTAConfig
    from claravid.eval.inference.collect import CollectSettings, collect
    from claravid.eval.inference.image_sums import ImageMeasures
    from claravid.eval.inference.run_model import ImageScore, evaluate_model, sample_key
    from claravid.eval.inference.sources import load_source
    from claravid.eval.inference.windows import (
        WindowConfig,
        class_probabilities,
        predict_labels,
        sliding_window_logits,
        window_starts,
    )
    from claravid.eval.inputs.datasets import open_data
    from claravid.eval.measures.boundary import boundary_iou
    from claravid.eval.measures.calibration_sums import calibration_bins
    from claravid.eval.measures.confusion import confusion_matrix
    from claravid.eval.measures.cross_view import CrossViewSums, cross_view
    from claravid.eval.report.build import build_report
    from claravid.eval.report.compare import compare_reports
    from claravid.eval.report.files import load_result
    from claravid.eval.report.folder import write_outputs
    from claravid.eval.reports import compare, merge
    from claravid.eval.run import evaluate, score_metrics
    from claravid.eval.settings import DataChoice, Evaluation, InferenceSettings, ReportSettings
else:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            # analysis (numpy)
            "CONVENTION": "claravid.eval.analysis.metrics",
            "IGNORE_INDEX": "claravid.eval.analysis.metrics",
            "iou_per_class": "claravid.eval.analysis.metrics",
            "mean_iou": "claravid.eval.analysis.metrics",
            "pixel_accuracy": "claravid.eval.analysis.metrics",
            "confusion_scores": "claravid.eval.analysis.metrics",
            "Bin": "claravid.eval.analysis.bins",
            "bin_names": "claravid.eval.analysis.bins",
            "fixed_bins": "claravid.eval.analysis.bins",
            "parse_edges": "claravid.eval.analysis.bins",
            "quantile_bins": "claravid.eval.analysis.bins",
            "Bootstrap": "claravid.eval.analysis.bootstrap",
            "correlation": "claravid.eval.analysis.stats",
            "stratify": "claravid.eval.analysis.miou_bins",
            "bin_mious": "claravid.eval.analysis.miou_bins",
            "EvalResult": "claravid.eval.analysis.table",
            "merge_results": "claravid.eval.analysis.table",
            # report (numpy, files, matplotlib)
            "build_report": "claravid.eval.report.build",
            "load_result": "claravid.eval.report.files",
            "write_outputs": "claravid.eval.report.folder",
            "compare_reports": "claravid.eval.report.compare",
            # inference (torch)
            "WindowConfig": "claravid.eval.inference.windows",
            "TTAConfig": "claravid.eval.inference.augment",
            "class_probabilities": "claravid.eval.inference.windows",
            "predict_labels": "claravid.eval.inference.windows",
            "sliding_window_logits": "claravid.eval.inference.windows",
            "window_starts": "claravid.eval.inference.windows",
            "confusion_matrix": "claravid.eval.measures.confusion",
            "ImageScore": "claravid.eval.inference.run_model",
            "evaluate_model": "claravid.eval.inference.run_model",
            "sample_key": "claravid.eval.inference.run_model",
            "open_data": "claravid.eval.inputs.datasets",
            "load_source": "claravid.eval.inference.sources",
            "collect": "claravid.eval.inference.collect",
            "CollectSettings": "claravid.eval.inference.collect",
            # runs: what each claravid-eval mode does, in one call
            "evaluate": "claravid.eval.run",
            "score_metrics": "claravid.eval.run",
            "merge": "claravid.eval.reports",
            "compare": "claravid.eval.reports",
            "DataChoice": "claravid.eval.settings",
            "InferenceSettings": "claravid.eval.settings",
            "ReportSettings": "claravid.eval.settings",
            "Evaluation": "claravid.eval.settings",
            "calibration_errors": "claravid.eval.analysis.calibration",
            "QualityTable": "claravid.eval.analysis.quality_table",
            "PairTable": "claravid.eval.analysis.quality_table",
            "boundary_iou": "claravid.eval.measures.boundary",
            "calibration_bins": "claravid.eval.measures.calibration_sums",
            "cross_view": "claravid.eval.measures.cross_view",
            "CrossViewSums": "claravid.eval.measures.cross_view",
            "ImageMeasures": "claravid.eval.inference.image_sums",
        },
    )

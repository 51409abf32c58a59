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

Training validates through the same windows and sums, from their rooms
(:func:`claravid.eval.inference.run_model.evaluate_model` scores a model image by image,
:func:`stratify` bins the scores)::

    from claravid.eval import WindowConfig, stratify
    from claravid.eval.inference.run_model import evaluate_model

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

    from claravid.eval import boundary_iou, calibration_bins, calibration_errors, cross_view

    inter, union = boundary_iou(pred, gt, num_classes=8)            # int64 [K] each
    count, conf_sum, correct = calibration_bins(probs, gt)          # 15 bins
    ece, mce = calibration_errors(count, conf_sum, correct)         # of summed bins
    sums = cross_view(depth_t, depth_s, c2w_t, c2w_s, K, pred_t, pred_s, gt_t, gt_s,
                      dynamic_t, dynamic_s, num_classes=8)          # a CrossViewSums

The names below are the ones a user calls, one per concept; everything else (the other
scores, bins, tables and sources) is reachable from its room. Each is imported on first use, so
``import claravid.eval`` (and the analysis and report layers) never loads torch unless a
torch-side name is asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from claravid.infra.lazy import lazy_exports

__all__ = [
    "Bootstrap",
    "CollectSettings",
    "DataChoice",
    "InferenceSettings",
    "ReportSettings",
    "TTAConfig",
    "WindowConfig",
    "boundary_iou",
    "build_report",
    "calibration_bins",
    "calibration_errors",
    "collect",
    "compare",
    "confusion_matrix",
    "cross_view",
    "evaluate",
    "load_result",
    "load_source",
    "mean_iou",
    "merge",
    "open_data",
    "score_metrics",
    "stratify",
    "write_outputs",
]

if TYPE_CHECKING:
    from claravid.eval.analysis.bootstrap import Bootstrap
    from claravid.eval.analysis.calibration import calibration_errors
    from claravid.eval.analysis.metrics import mean_iou
    from claravid.eval.analysis.miou_bins import stratify
    from claravid.eval.inference.augment import TTAConfig
    from claravid.eval.inference.collect import CollectSettings, collect
    from claravid.eval.inference.sources import load_source
    from claravid.eval.inference.windows import WindowConfig
    from claravid.eval.inputs.datasets import open_data
    from claravid.eval.measures.boundary import boundary_iou
    from claravid.eval.measures.calibration_sums import calibration_bins
    from claravid.eval.measures.confusion import confusion_matrix
    from claravid.eval.measures.cross_view import cross_view
    from claravid.eval.report.build import build_report
    from claravid.eval.report.files import load_result
    from claravid.eval.report.folder import write_outputs
    from claravid.eval.reports import compare, merge
    from claravid.eval.run import evaluate, score_metrics
    from claravid.eval.settings import DataChoice, InferenceSettings, ReportSettings
else:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "mean_iou": "claravid.eval.analysis.metrics",
            "Bootstrap": "claravid.eval.analysis.bootstrap",
            "stratify": "claravid.eval.analysis.miou_bins",
            "build_report": "claravid.eval.report.build",
            "load_result": "claravid.eval.report.files",
            "write_outputs": "claravid.eval.report.folder",
            "WindowConfig": "claravid.eval.inference.windows",
            "TTAConfig": "claravid.eval.inference.augment",
            "confusion_matrix": "claravid.eval.measures.confusion",
            "open_data": "claravid.eval.inputs.datasets",
            "load_source": "claravid.eval.inference.sources",
            "collect": "claravid.eval.inference.collect",
            "CollectSettings": "claravid.eval.inference.collect",
            "evaluate": "claravid.eval.run",
            "score_metrics": "claravid.eval.run",
            "merge": "claravid.eval.reports",
            "compare": "claravid.eval.reports",
            "DataChoice": "claravid.eval.settings",
            "InferenceSettings": "claravid.eval.settings",
            "ReportSettings": "claravid.eval.settings",
            "calibration_errors": "claravid.eval.analysis.calibration",
            "boundary_iou": "claravid.eval.measures.boundary",
            "calibration_bins": "claravid.eval.measures.calibration_sums",
            "cross_view": "claravid.eval.measures.cross_view",
        },
    )

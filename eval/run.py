"""An evaluation in one call: what ``claravid-eval`` does with a model, label maps or a CSV.

::

    from claravid.eval import DataChoice, ReportSettings, evaluate

    done = evaluate("runs/exp/report", checkpoint="runs/exp/best.pt",
                    data=DataChoice(split="val"), report=ReportSettings(bins=5))
    print(done.report["overall"]["miou"])

:func:`evaluate` checks the output folders, loads the model, resolves the data (the call's
choice, then what the model recorded, then the defaults), runs the model or reads the label
maps, builds the report and writes its folder; :func:`score_metrics` does the same for any
per-image metric of a CSV. Neither prints: the command line (:mod:`claravid.eval.cli.evaluate`)
prints
what they return. Merging and comparing saved reports is :mod:`claravid.eval.reports`.
"""

from __future__ import annotations

import contextlib
import functools
import os
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, TypeVar

import numpy as np

from claravid.data.splits import SplitBalanceWarning
from claravid.eval.analysis.units import DATASETS, default_cluster, unit_labels
from claravid.eval.report.files import REPORT, check_report_kind
from claravid.eval.reports import warn_outside_edges
from claravid.eval.settings import (
    SELECTION,
    DataChoice,
    Evaluation,
    InferenceSettings,
    ReportSettings,
    check_classes,
    check_type,
)
from claravid.infra.cli import UsageError
from claravid.infra.files import check_output_dir, output_lock

if TYPE_CHECKING:  # types only: the call imports torch's side when it runs
    from claravid.eval.analysis.bootstrap import Bootstrap
    from claravid.eval.inference.collect import Collected
    from claravid.eval.inference.quality_plan import QualityPlan
    from claravid.eval.inputs.datasets import EvalData


def resolve_data(
    choice: DataChoice,
    defaults: dict[str, Any],
    *,
    hint: str = "",
    default_split: dict[str, str] | None = None,
) -> dict[str, Any]:
    """The data to open: ``choice`` first, then what the model recorded, then the defaults
    (the one rule of evaluations and ``scores``).

    Args:
        choice: the call's choice.
        defaults: what the model (or the label maps) recorded.
        hint: added to the message when no root is known.
        default_split: the split per dataset kind when neither gives one (default ``val``).

    Raises:
        UsageError: no root anywhere, an unknown recorded dataset kind, ``masks`` or a ClaraVid
            selection with other data.
    """
    root = choice.root or defaults.get("data")
    if root is None:
        raise UsageError(f"--data is required: the dataset root to evaluate on{hint}")
    dataset = choice.dataset or defaults.get("dataset") or "claravid"
    if dataset not in DATASETS:  # DataChoice checks its own; a record may be anything
        raise UsageError(
            f"the recorded dataset kind {dataset!r} is unknown; pass --dataset (one of "
            f"{', '.join(DATASETS)})"
        )
    if choice.masks is not None and dataset != "folder":
        raise UsageError(f"--masks does nothing with --dataset {dataset}; drop it")
    if choice.selection and dataset != "claravid":
        flag = "--" + next(iter(choice.selection))
        raise UsageError(
            f"{flag} selects ClaraVid frames; it does nothing with --dataset {dataset}"
        )
    selection = {}
    if dataset == "claravid" and defaults.get("dataset", "claravid") == "claravid":
        # ClaraVid as in training: the same selection and split settings, so --split val is
        # exactly the frames training held out.
        selection = {k: defaults[k] for k in (*SELECTION, "split_config") if k in defaults}
    selection.update(choice.selection)
    return {
        "root": Path(root),
        "dataset": dataset,
        "split": choice.split or defaults.get("split") or (default_split or {}).get(dataset, "val"),
        "palette": choice.palette or defaults.get("palette"),
        "masks": choice.masks,
        "selection": selection,
    }


P = ParamSpec("P")
R = TypeVar("R")


def _one_writer(function: Callable[P, R]) -> Callable[P, R]:
    """Run ``function`` (whose first argument is the output folder) holding that folder, so two
    evaluations writing one folder do not both finish with the second silently replacing the
    first (`output_lock`). Under ``torchrun`` rank 0 alone holds it (the one that writes)."""

    @functools.wraps(function)
    def held(*args: P.args, **kwargs: P.kwargs) -> R:
        output = args[0] if args else kwargs["output"]
        main = os.environ.get("RANK", "0") == "0"
        with output_lock(output) if main else contextlib.nullcontext():  # type: ignore[arg-type]
            return function(*args, **kwargs)

    return held


@_one_writer
def evaluate(
    output: str | Path,
    *,
    checkpoint: str | Path | None = None,
    onnx: str | Path | None = None,
    predictions: str | Path | None = None,
    data: DataChoice | None = None,
    inference: InferenceSettings | None = None,
    report: ReportSettings | None = None,
    save_predictions: str | Path | None = None,
    allow_missing: bool = False,
    workers: int = 0,
    overwrite: bool = False,
    progress: bool = False,
) -> Evaluation:
    """Evaluate a checkpoint, an ONNX file or saved label maps into the report folder ``output``.

    Under ``torchrun`` every rank calls it; rank 0 writes the report, the others return
    ``report=None``.

    Args:
        output: the report folder.
        checkpoint, onnx, predictions: what to evaluate (exactly one).
        data: the images (default: what the checkpoint recorded).
        inference: windows, device, precision (models only).
        report: bins, groups, measures, tiles, intervals, and the measures beyond mIoU
            (boundary, calibration, consistency: each on where the source and data allow it).
        save_predictions: also write the model's label maps into this folder.
        allow_missing: skip images without a saved prediction (listed in ``skipped``).
        workers: processes for complexity and image decoding.
        overwrite: replace folders this tool did not write.
        progress: show a progress bar.

    Raises:
        UsageError: a user's mistake (bad combination, foreign output folder, mismatched
            palette, missing data...), before the inference starts where it can be seen then.
    """
    from claravid.eval.inference.collect import CollectSettings, collect
    from claravid.infra import distributed
    from claravid.infra.cli import check_device

    data, inference, report = _checked_arguments(checkpoint, onnx, predictions, data, inference,
                                                 report)  # fmt: skip
    output = Path(output)
    check_device(inference.device)  # one line, not CUDA's traceback
    info = distributed.init_distributed(inference.device)
    _check_outputs(output, predictions, save_predictions, overwrite)
    # Every rank has checked the untouched folders; only now may any rank write to them.
    distributed.barrier()
    model, run, source = _model_and_source(checkpoint, onnx, predictions, data, inference, info)
    opened, fold = _open(data, model, run, predictions)
    plan, intervals = _plan_before_inference(opened, report, has_scores=model is not None)
    _describe_run(source, opened, fold, report)
    settings = CollectSettings(
        window=run.window if run is not None else None,
        measures=report.measures,
        tile_size=report.tiles,
        hardest=report.hardest,
        workers=workers,
        device=info.device,
        save_predictions=save_predictions,
        allow_missing=allow_missing,
        progress=info.is_main and progress,
        quality=plan,
        fold=fold,
    )
    collected = collect(opened, model=model, predictions=predictions, settings=settings,
                        source=source)  # fmt: skip
    if not info.is_main:
        distributed.barrier()  # rank 0 writes the report meanwhile
        return Evaluation(output, None, skipped=collected.skipped)
    try:
        numbers = _write_report(output, collected, opened, report, intervals, source,
                                predictions, save_predictions, fold)  # fmt: skip
    finally:
        distributed.barrier()  # the other ranks wait for the report, even when it failed
    return Evaluation(output, numbers, collected.result, collected.skipped)


def _describe_run(source: dict[str, Any], opened: Any, fold: Any, report: ReportSettings) -> None:
    """What the report's ``source`` says beside the model: the data, the fold through which a
    fine model is scored (another palette), the classes it can predict, measures and tiles."""
    source.update(opened.describe)
    if fold is not None:
        source["fold"] = fold.describe()
    source["predictable"] = predictable_classes(opened.palette, fold)
    source["measures"] = list(report.measures)
    if report.tiles is not None:
        source["tiles"] = report.tiles


def _checked_arguments(
    checkpoint: str | Path | None,
    onnx: str | Path | None,
    predictions: str | Path | None,
    data: DataChoice | None,
    inference: InferenceSettings | None,
    report: ReportSettings | None,
) -> tuple[DataChoice, InferenceSettings, ReportSettings]:
    """One source, and settings of their types (each defaulted)."""
    if sum(x is not None for x in (checkpoint, onnx, predictions)) != 1:
        raise UsageError("give exactly one of --checkpoint, --onnx and --predictions")
    # A root given as data= is the usual slip: the message shows the call that was meant.
    meant = f"DataChoice(root={str(data)!r})" if isinstance(data, (str, Path)) else None
    check_type(data, DataChoice, "data", meant or "DataChoice(root='/data/claravid')")
    check_type(inference, InferenceSettings, "inference", "InferenceSettings(scale=0.5)")
    check_type(report, ReportSettings, "report", "ReportSettings(bins=5)")
    return data or DataChoice(), inference or InferenceSettings(), report or ReportSettings()


def _check_outputs(
    output: Path,
    predictions: str | Path | None,
    save_predictions: str | Path | None,
    overwrite: bool,
) -> None:
    """The report folder and the label maps' folder are this tool's (or may be overwritten)."""
    from claravid.eval.inputs.label_maps import MARKER

    check_output_dir(output, marker=REPORT, overwrite=overwrite)
    check_report_kind(output, scores=False, overwrite=overwrite)
    if save_predictions is not None:
        if predictions is not None:
            raise UsageError("--save-predictions needs a model (--checkpoint or --onnx)")
        check_output_dir(save_predictions, marker=MARKER, overwrite=overwrite,
                         what="--save-predictions")  # fmt: skip


def _plan_before_inference(
    opened: EvalData, report: ReportSettings, *, has_scores: bool
) -> tuple[QualityPlan, Bootstrap]:
    """(the measures beyond mIoU to compute, the interval settings): what would fail after the
    inference (a measure the source or data cannot give, groups, bins, the bootstrap's memory)
    is refused now."""
    from claravid.eval.inference.quality_plan import plan_quality
    from claravid.eval.inputs.pass_frames import pairs_unavailable

    # Refused now (calibration of label maps, consistency of data without depth), not after.
    asked = {"boundary_iou": report.boundary, "calibration": report.calibration,
             "consistency": report.consistency}  # fmt: skip
    plan = plan_quality(asked, has_scores=has_scores, pairs_reason=pairs_unavailable(opened))
    if report.group_by is not None:
        opened.groups(report.group_by)  # fails now, not after the inference
    report.check_bins(len(opened))
    check_classes(report.classes, opened.palette.names)  # before the inference, not after
    intervals = report.intervals(opened.attributes, default_cluster(opened.name, opened.attributes))
    # Refused now, not after the inference: the images' clusters are known before it runs.
    intervals.check_memory(unit_labels(opened.paths, opened.attributes, intervals.cluster))
    return plan, intervals


def _write_report(
    output: Path,
    collected: Collected,
    opened: EvalData,
    report: ReportSettings,
    intervals: Bootstrap,
    source: dict[str, Any],
    predictions: str | Path | None,
    save_predictions: str | Path | None,
    fold: Any,
) -> dict[str, Any]:
    """Build the report from the collected table and write its folder (rank 0): its numbers.
    ``fold`` maps saved fine label maps drawn among the hardest images (None: no fold)."""
    from claravid.eval.inference.hardest import hardest_items
    from claravid.eval.inputs.label_maps import write_marker
    from claravid.eval.report.build import build_report
    from claravid.eval.report.folder import write_outputs

    result = collected.result
    report.check_bins(len(result.paths))
    numbers = build_report(result, bins=report.bins, edges=report.edges,
                           group_by=report.group_by, bootstrap=intervals,
                           classes=report.classes)  # fmt: skip
    warn_outside_edges(numbers, result.complexity["delent"], len(result.paths))
    dirs = [Path(d) for d in (predictions, save_predictions) if d is not None]
    items = hardest_items(result, opened, report.hardest, collected.hardest, dirs,
                          fold if predictions is not None else None)  # fmt: skip
    items += collected.pairs  # the pairs of lowest consistency, below the hardest images
    write_outputs(output, numbers, result, items, opened.palette.colors)
    if save_predictions is not None:
        write_marker(save_predictions, opened.palette, source)
    return numbers


def _model_and_source(
    checkpoint: Any, onnx: Any, predictions: Any, data: DataChoice, inference: InferenceSettings,
    info: Any,
) -> tuple[Any, Any, dict[str, Any]]:  # fmt: skip
    """The loaded model (None for label maps), how it runs, and the report's ``source``."""
    import torch

    from claravid.eval.inference.sources import load_source, resolve_settings
    from claravid.infra.precision import autocast_dtype, precision_name

    if predictions is not None:
        return None, None, {"kind": "predictions", "predictions": str(predictions)}
    threads = torch.get_num_threads() if info.device.type == "cpu" else None
    model = load_source(checkpoint, onnx, device=info.device, threads=threads,
                        provider=inference.provider)  # fmt: skip
    run = resolve_settings(
        model, window=inference.window, stride=inference.stride, scale=inference.scale,
        batch_size=inference.batch_size, palette=data.palette, precision=inference.precision,
        statistics=inference.statistics, tta=inference.tta, gsd=inference.gsd,
    )  # fmt: skip
    window = run.window
    assert window.size is not None and window.stride is not None  # resolved for the model
    source = model.describe()
    source["window"] = {"size": list(window.size), "stride": list(window.stride),
                        "scale": window.scale,
                        "tta": None if window.tta is None else window.tta.describe()}  # fmt: skip
    if model.kind == "onnx":  # runs as exported: the file's number format, None when foreign
        source["dtype"] = getattr(model.model, "dtype", None)
        source["precision"] = None  # no autocast: ONNX Runtime runs the file's own types
    else:
        source["precision"] = precision_name(autocast_dtype(window.precision, info.device))
    source["settings"] = run.describe()
    return model, run, source


def _open(data: DataChoice, model: Any, run: Any, predictions: Any) -> tuple[Any, Any]:
    """Open the data: the call's choice, then the model's (or label maps') record; with the
    fold that scores a fine model through the data's palette (None: no fold)."""
    from claravid.eval.inputs.datasets import open_data
    from claravid.eval.inputs.label_maps import predictions_defaults

    if model is not None:
        defaults = model.defaults
        hint = " (the checkpoint does not record its data)" if model.kind == "checkpoint" else ""
    else:  # saved label maps: the palette their predictions.json names
        defaults, hint = predictions_defaults(predictions, data.palette), ""
    spec = resolve_data(data, defaults, hint=hint)
    try:
        with warnings.catch_warnings():
            if model is not None and _split_as_trained(data, spec, defaults):
                # The training run printed this warning for these very split settings.
                warnings.simplefilter("ignore", SplitBalanceWarning)
            opened = open_data(
                spec["root"],
                dataset=spec["dataset"],
                split=spec["split"],
                palette=spec["palette"],
                masks=spec["masks"],
                selection=spec["selection"],
            )
    except FileNotFoundError as exc:
        if data.split is not None and str(exc).startswith("split file not found"):
            raise UsageError(  # the user's own path, not the checkpoint's
                f"--split {data.split}: no such split file; pass train, val, test, all or the "
                "path of an existing split file"
            ) from None
        if data.root is not None or model is None or "data" not in model.defaults:
            raise
        raise UsageError(  # the data moved since training: say where the path came from
            f"{exc} (that path comes from the checkpoint {model.path}; pass --data to give the "
            "data's new place)"
        ) from None
    if model is not None:
        fold = scoring_fold(model_classes(model.defaults), model.num_classes, opened.palette,
                            model.defaults.get("palette"))  # fmt: skip
    else:
        fold = scoring_fold(defaults.get("model_classes"), None, opened.palette, None)
    return opened, fold


def predictable_classes(palette: Any, fold: Any) -> list[str]:
    """The palette classes a model of ClaraVid's classes can predict: those the fold reaches,
    else those the palette's ClaraVid side maps some class to (``source["predictable"]``)."""
    from claravid.data.palette_fold import reachable_from_palette

    reach = fold.reachable if fold is not None else reachable_from_palette(palette)
    return [name for name, ok in zip(palette.names, reach, strict=True) if ok]


def model_classes(defaults: dict[str, Any]) -> tuple[str, ...] | None:
    """The class names a model predicts, from what its file records (an ONNX file's palette, a
    checkpoint's training palette); None when it records none or its palette is gone."""
    from claravid.data.palettes import PaletteError, load_palette

    names = (defaults.get("palette_info") or {}).get("names")
    if isinstance(names, list) and names:
        return tuple(str(n) for n in names)
    recorded = defaults.get("palette")
    if not isinstance(recorded, str) or not recorded:
        return None
    try:
        return load_palette(recorded).names
    except PaletteError:
        return None


def scoring_fold(
    names: Sequence[str] | None, count: int | None, palette: Any, trained: str | None
) -> Any:
    """How a model (or its label maps) of classes ``names`` (or ``count`` classes) is scored
    on ``palette``: None when it predicts the palette's classes; a
    :class:`~claravid.data.palette_fold.PaletteFold` when it predicts ClaraVid's 19 classes
    and the palette is another.

    Raises:
        UsageError: any other model whose class count differs from the palette's.
    """
    from claravid.data.palette_fold import fold_palette, is_fine

    if names is not None and tuple(names) != tuple(palette.names) and is_fine(names):
        return fold_palette(names, palette)
    if count is not None and count != palette.num_classes:
        was = f" --palette {trained}" if trained else " --palette"
        raise UsageError(
            f"the model predicts {count} classes but palette {palette.name} has "
            f"{palette.num_classes}; pass the palette it was trained with ({was.strip()}); only "
            "a model of ClaraVid's 19 classes (palette claravid) is scored through another palette"
        )
    return None


def _split_as_trained(data: DataChoice, spec: dict[str, Any], defaults: dict[str, Any]) -> bool:
    """Whether the images are split as in the model's training run: the recorded ClaraVid
    root, selection and split settings, none of them overridden."""
    recorded = defaults.get("data")
    if spec["dataset"] != "claravid" or recorded is None or "split_config" not in defaults:
        return False
    if data.selection or defaults.get("dataset", "claravid") != "claravid":
        return False
    return Path(recorded).resolve() == Path(spec["root"]).resolve()


def score_metrics(
    scores: str | Path,
    output: str | Path,
    *,
    data: DataChoice,
    report: ReportSettings | None = None,
    workers: int = 0,
    overwrite: bool = False,
) -> Evaluation:
    """The complexity analysis of any per-image metric of a CSV (``path`` + numeric columns).

    No model and no labels: the images' complexity, binned, grouped and correlated with each
    metric, with cluster bootstrap intervals.

    Raises:
        UsageError: no data root, a foreign output folder, a bad CSV, images not in the data.
    """
    from claravid.eval.analysis.metric_bins import metric_report
    from claravid.eval.analysis.units import group_indices
    from claravid.eval.inference.complexity_job import ComplexityJob
    from claravid.eval.inputs.datasets import open_data
    from claravid.eval.inputs.metric_csv import match_images, read_metrics_csv
    from claravid.eval.report.folder import write_metric_outputs

    check_type(data, DataChoice, "data", "DataChoice(root='/data/uavid', dataset='uavid')")
    check_type(report, ReportSettings, "report", "ReportSettings(bins=5)")
    report = report or ReportSettings()
    if data.root is None:
        raise UsageError("scores needs --data: the dataset root the CSV's paths belong to")
    # The rule of every evaluation, without a model's record; ClaraVid defaults to all frames.
    spec = resolve_data(data, {}, default_split={"claravid": "all"})
    output = Path(output)
    check_output_dir(output, marker=REPORT, overwrite=overwrite)
    check_report_kind(output, scores=True, overwrite=overwrite)
    csv_paths, metrics, csv_rows = read_metrics_csv(scores, spec["root"])
    opened = open_data(
        spec["root"],
        dataset=spec["dataset"],
        split=spec["split"],
        palette=data.palette,
        masks=spec["masks"],
        selection=spec["selection"],
        labels=False,
    )
    if report.group_by is not None:
        opened.groups(report.group_by)  # fails now, before the complexity is measured
    settings = report.intervals(opened.attributes, default_cluster(opened.name, opened.attributes))
    order = match_images(csv_paths, opened.paths, Path(scores), csv_rows)
    paths = [opened.paths[i] for i in order]
    report.check_bins(len(paths))
    attributes = {a: [v[i] for i in order] for a, v in opened.attributes.items()}
    clusters = unit_labels(paths, attributes, settings.cluster)
    settings.check_memory(clusters)  # before the complexity of every image is measured
    # The one grouping rule of every report (viewpoint = mission/viewpoint).
    groups = None if report.group_by is None else group_indices(paths, attributes, report.group_by)
    values = ComplexityJob(paths, report.measures, threads=max(1, workers)).result()
    complexity = {m: np.asarray(values[m], dtype=np.float64) for m in report.measures}
    numbers = metric_report(paths, metrics, complexity, clusters, settings,
                            bins=report.bins, edges=report.edges, groups=groups)  # fmt: skip
    binning = {**numbers.pop("binning", {}), "group_by": report.group_by}
    numbers["source"] = {"kind": "scores", "scores": str(scores), **opened.describe,
                         "measures": list(report.measures), "binning": binning}  # fmt: skip
    text = write_metric_outputs(output, numbers)
    return Evaluation(output, numbers, text=text)

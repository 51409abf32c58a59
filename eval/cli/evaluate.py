"""``claravid-eval``: mIoU per delentropy bin, correlations and a readable report, from any model.

Four jobs, each with the flags it takes: evaluating a model or its saved label maps (the
command itself), and three subcommands that need no model: ``merge`` (report folders into one,
or re-binned), ``compare`` (reports side by side, with the gaps and their intervals) and
``scores`` (any per-image metric of a CSV against complexity).

::

    claravid-eval --checkpoint runs/exp/best.pt --split val --output runs/exp/report
    claravid-eval --onnx model.onnx --data /data/claravid --palette uavid --output rep
    claravid-eval --predictions preds/ --data /data/claravid --palette uavid --output rep
    claravid-eval --predictions preds/ --data /data/claravid --tiles 630 --output rep  # + tiles
    claravid-eval merge part0/ part1/ --output all/            # job-array parts -> one report
    claravid-eval merge rep/ --edges 4,4.5,5,5.5 --output rep-fixed   # re-bin, no model
    claravid-eval compare a/report.json b/report.json --output cmp/   # gaps with intervals
    claravid-eval scores psnr.csv --data /data/uavid --dataset uavid --split test \
        --group-by sequence --measures delent,glcment,pixent --output psnr-rep   # any metric
    torchrun --nproc_per_node=8 -m claravid.eval --checkpoint best.pt --output rep   # many GPUs

Exit 0 on success, 1 when some images were skipped (``--allow-missing``; listed), 2 for a
user's mistake (one line; ``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.units import CLUSTER_UNITS, DATASETS, GROUP_BY
from claravid.eval.inference.augment import tta_from_flags
from claravid.eval.report.files import REPORT
from claravid.eval.settings import (
    SELECTION,
    DataChoice,
    InferenceSettings,
    ReportSettings,
)
from claravid.infra.cli import (
    EXIT_PARTIAL,
    UsageError,
    add_checkpoint_flag,
    add_data_flag,
    add_debug_flag,
    add_device_flag,
    add_output_flag,
    add_precision_flag,
    add_progress_flag,
    add_selection_flags,
    add_statistics_flag,
    add_tta_flags,
    add_window_flags,
    add_workers_flag,
    non_negative_int,
    positive_float,
    positive_int,
    run_cli,
)
from claravid.models.backbones.specs import NAMED_STATISTICS
from claravid.models.export.runtime import PROVIDERS

PROG = "claravid-eval"
#: The model sources of the command itself (exactly one).
SOURCES = ("checkpoint", "onnx", "predictions")
#: The measures beyond mIoU: --name and --no-name (None: not given).
QUALITY_FLAGS = ("boundary", "calibration", "consistency")
#: Model flags a source has no use for: label maps are read, not predicted, and a checkpoint
#: runs in PyTorch (the ONNX file's --precision is refused where the precision is resolved).
_IDLE_FOR_SOURCE = {"checkpoint": ("provider",),
                    "predictions": ("provider", "precision", "statistics", "tta",
                                    "tta_scales", "tta_size")}  # fmt: skip


def _epilog() -> str:
    return __doc__.split("::", 1)[1].split("Exit 0")[0]


def build_parser() -> argparse.ArgumentParser:
    """The arguments of ``claravid-eval`` itself: evaluating a model or saved label maps (also
    ``python -m claravid.eval``). The subcommands have their own (`build_merge_parser`,
    `build_compare_parser`, `build_scores_parser`)."""
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Evaluate semantic segmentation per scene-complexity (delentropy) bin. "
        "Subcommands without a model: merge, compare, scores (claravid-eval merge --help).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=_epilog(),
    )
    group = p.add_argument_group("what to evaluate (exactly one)")
    src = group.add_mutually_exclusive_group(required=True)
    add_checkpoint_flag(src)
    src.add_argument("--onnx", type=Path, help="ONNX model (claravid-export), run by onnxruntime")
    src.add_argument(
        "--predictions", type=Path, metavar="DIR", help="saved label maps DIR/<key>.png"
    )
    _add_data(p, labels=True)
    infer = p.add_argument_group("inference")
    add_window_flags(infer)
    add_tta_flags(infer)
    infer.add_argument(
        "--gsd", type=positive_float, metavar="METRES",
        help="the data's ground sampling distance: images are resized to the model's recorded "
        "GSD (instead of --scale)",
    )  # fmt: skip
    add_statistics_flag(infer, NAMED_STATISTICS)
    add_device_flag(infer)
    add_precision_flag(infer)
    infer.add_argument(
        "--provider", metavar=_choices(PROVIDERS), help="ONNX Runtime provider (--onnx)"
    )
    rep = p.add_argument_group("report", "-o/--output is the report folder.")
    add_output_flag(rep, required=True)
    _add_binning(rep, measures=True)
    rep.add_argument(
        "--tiles",
        type=positive_int,
        metavar="T",
        help="also bin tiles of about T px by their own delentropy (e.g. 630)",
    )
    rep.add_argument(
        "--hardest", type=non_negative_int, help="overlays of the K hardest images (default 4)"
    )
    for name, what in (("boundary", "Boundary IoU per class (default on)"),
                       ("calibration", "ECE, MCE, reliability diagram (default on with scores)"),
                       ("consistency", "cross-view consistency of consecutive frames (default on "
                                       "with depth and poses)")):  # fmt: skip
        rep.add_argument(f"--{name}", action=argparse.BooleanOptionalAction, help=what)
    _add_classes(rep)
    rep.add_argument("--save-predictions", type=Path, metavar="DIR", help="write label maps")
    rep.add_argument("--allow-missing", action="store_true", help="skip images w/o prediction")
    add_workers_flag(rep, "complexity and image decoding")
    _add_common(p, rep)
    return p


def _add_classes(group: Any) -> None:
    group.add_argument(
        "--classes",
        metavar="A,B,...",
        help="also the mIoU over these palette classes, in every row (e.g. Road,Building)",
    )


def build_merge_parser() -> argparse.ArgumentParser:
    """``claravid-eval merge REPORT... -o DIR``: report folders into one report, or one re-binned
    (no model, no images)."""
    p = _subparser("merge", "Merge report folders (job-array parts, or one to re-bin) into one "
                   "report, without a model or the images.")  # fmt: skip
    p.add_argument("reports", nargs="+", type=Path, metavar="REPORT", help="report folders")
    rep = p.add_argument_group("report", "-o/--output is the merged report's folder.")
    add_output_flag(rep, required=True)
    _add_binning(rep, measures=False)
    _add_classes(rep)
    _add_common(p, rep)
    return p


def build_compare_parser() -> argparse.ArgumentParser:
    """``claravid-eval compare A B...``: reports side by side, and each one's gaps against the
    first with cluster bootstrap intervals."""
    p = _subparser("compare", "Show reports side by side: the bin tables, and each report's "
                   "gaps against the first with cluster bootstrap intervals.")  # fmt: skip
    p.add_argument(
        "reports",
        nargs="+",
        type=Path,
        metavar="REPORT",
        help="report folders or report.json files; the first is the baseline",
    )
    p.add_argument(
        "--oracle",
        type=Path,
        metavar="REPORT",
        help="a target-supervised model's report: the first report is then the source-only "
        "model, the others adapted ones, and the comparison adds the share of the gap each "
        "closes, per bin and per class",
    )
    rep = p.add_argument_group("output", "Unset, the comparison is only printed.")
    add_output_flag(rep)
    _add_common(p, rep)
    return p


def build_scores_parser() -> argparse.ArgumentParser:
    """``claravid-eval scores CSV --data ROOT -o DIR``: any per-image metric against complexity
    (no model, no labels)."""
    p = _subparser("scores", "The complexity analysis of any per-image metric: a CSV of a path "
                   "column and numeric columns, against the images' delentropy.")  # fmt: skip
    p.add_argument("scores", type=Path, metavar="CSV", help="per-image metrics (path + numeric "
                   "columns)")  # fmt: skip
    _add_data(p, labels=False)
    rep = p.add_argument_group("report", "-o/--output is the report folder.")
    add_output_flag(rep, required=True)
    _add_binning(rep, measures=True)
    add_workers_flag(rep, "complexity and image decoding")
    _add_common(p, rep)
    return p


def _subparser(name: str, description: str) -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        prog=f"{PROG} {name}",
        description=description,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=_epilog(),
    )


def _add_data(p: argparse.ArgumentParser, *, labels: bool) -> None:
    data = p.add_argument_group(
        "data",
        "Unset, the root, split, palette and selection are the checkpoint's." if labels else None,
    )
    add_data_flag(data)
    # Choices shown, checked by DataChoice (the Python API's check and message).
    data.add_argument(
        "--dataset", metavar=_choices(DATASETS), help="kind of data (default claravid)"
    )
    data.add_argument("--split", help="train, val, test or all (default val)")
    if labels:  # scores reads images only: no labels, no label palette
        data.add_argument("--palette", help="palette name or YAML (default: the checkpoint's)")
        data.add_argument("--masks", type=Path, help="label folder mirroring --data (folder only)")
    add_selection_flags(data)


def _add_binning(rep: Any, *, measures: bool) -> None:
    rep.add_argument("--bins", type=positive_int, help="quantile bins of delentropy (default 3)")
    rep.add_argument("--edges", help="fixed delentropy edges e1,e2,... instead of --bins")
    rep.add_argument(
        "--group-by",
        metavar=_choices(GROUP_BY),
        help="rows per mission, viewpoint, UAVid sequence or folder",
    )
    if measures:  # a merge keeps the measures its reports carry
        rep.add_argument("--measures", help="delent,glcment,pixent (default delent)")


def _add_common(p: argparse.ArgumentParser, rep: Any) -> None:
    rep.add_argument("--overwrite", action="store_true", help="replace a foreign output folder")
    add_progress_flag(rep)
    _add_uncertainty(p)
    add_debug_flag(p)


def _choices(values: Any) -> str:
    return "{" + ",".join(values) + "}"


def _add_uncertainty(p: argparse.ArgumentParser) -> None:
    unc = p.add_argument_group("uncertainty (cluster percentile bootstrap)")
    unc.add_argument("--bootstrap", type=int, default=1000, help="resamples (default 1000; 0 off)")
    unc.add_argument(
        "--cluster",
        help=f"resampled unit: {', '.join(CLUSTER_UNITS)} (default block for ClaraVid, "
        "sequence for UAVid, folder for folder data)",
    )
    unc.add_argument("--ci-level", type=float, default=0.95, help="interval level (default 0.95)")
    unc.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")


def _check_bins(args: argparse.Namespace) -> None:
    if getattr(args, "bins", None) is not None and getattr(args, "edges", None) is not None:
        raise UsageError("give --bins or --edges, not both")


def _source(args: argparse.Namespace) -> str:
    """The model source given (argparse made it exactly one), its idle flags refused, and the
    settings made: they check themselves with the messages the Python API gives, so a mistake
    stops here, before any work."""
    _check_bins(args)
    source = next(name for name in SOURCES if getattr(args, name) is not None)
    for name in _IDLE_FOR_SOURCE.get(source, ()):
        if getattr(args, name) is not None:
            flag = name.replace("_", "-")
            raise UsageError(f"--{flag} does nothing with --{source}; drop it")
    if source == "predictions" and args.flip:
        raise UsageError("--flip does nothing with --predictions; drop it")
    from claravid.infra.precision import flag_precision

    args.precision = flag_precision(args.precision, pytorch=source == "checkpoint")
    args.settings = {"data": _data_choice(args), "inference": _inference(args),
                     "report": _report_settings(args)}  # fmt: skip
    return source


def _data_choice(args: argparse.Namespace) -> DataChoice:
    return DataChoice(
        root=args.data,
        dataset=args.dataset,
        split=args.split,
        palette=getattr(args, "palette", None),
        masks=getattr(args, "masks", None),
        # --missions/--altitude/--direction as given: DataChoice splits them into lists.
        selection={n: getattr(args, n) for n in SELECTION if getattr(args, n) is not None},
    )


def _inference(args: argparse.Namespace) -> InferenceSettings:
    return InferenceSettings(window=args.window, stride=args.stride, scale=args.scale,
                             batch_size=args.batch_size, device=args.device,
                             precision=args.precision, provider=args.provider,
                             statistics=args.statistics, gsd=args.gsd,
                             tta=tta_from_flags(args.tta, args.tta_scales, args.flip,
                                                args.tta_size))  # fmt: skip


def _report_settings(args: argparse.Namespace) -> ReportSettings:
    intervals = Bootstrap(resamples=args.bootstrap, level=args.ci_level, seed=args.seed)
    hardest = getattr(args, "hardest", None)
    quality = {name: getattr(args, name, None) for name in QUALITY_FLAGS}
    return ReportSettings(bins=getattr(args, "bins", None) or 3,
                          edges=getattr(args, "edges", None),
                          group_by=getattr(args, "group_by", None),
                          measures=getattr(args, "measures", None) or "delent",
                          tiles=getattr(args, "tiles", None),
                          hardest=4 if hardest is None else hardest,
                          bootstrap=intervals, cluster=args.cluster,
                          classes=getattr(args, "classes", None), **quality)  # fmt: skip


def _print_done(out: Path, report: dict[str, Any], what: str = "plots and confusions") -> None:
    from claravid.eval.report.markdown import bin_table
    from claravid.eval.report.quality_text import quality_table

    print(bin_table(report))
    extra = quality_table(report)
    if extra:
        print(f"\n{extra}")
    for message in (report.get("uncertainty") or {}).get("warnings", []):
        print(f"{PROG}: warning: {message}", file=sys.stderr)
    print(f"\nreport: {out / 'report.md'} ({out / REPORT}, {what} beside)")


def _run_compare(args: argparse.Namespace) -> int:
    from claravid.eval.reports import compare

    report = _report_settings(args)
    print(compare(args.reports, args.output, report.bootstrap, report.cluster,
                  oracle=args.oracle, overwrite=args.overwrite))  # fmt: skip
    if args.output is not None:
        print(f"comparison: {args.output / 'compare.md'} and {args.output / 'compare.png'}")
    return 0


def _run_merge(args: argparse.Namespace) -> int:
    from claravid.eval.reports import merge

    _check_bins(args)
    done = merge(args.reports, args.output, _report_settings(args), overwrite=args.overwrite)
    assert done.report is not None  # only a torchrun rank other than 0 has none
    _print_done(done.output, done.report)
    return 0


def _run_evaluation(args: argparse.Namespace) -> int:
    from claravid.eval.run import evaluate

    _source(args)
    done = evaluate(
        args.output,
        checkpoint=args.checkpoint,
        onnx=args.onnx,
        predictions=args.predictions,
        data=args.settings["data"],
        inference=args.settings["inference"],
        report=args.settings["report"],
        save_predictions=args.save_predictions,
        allow_missing=args.allow_missing,
        workers=args.workers,
        overwrite=args.overwrite,
        progress=not args.no_progress,
    )
    if done.report is None:  # another torchrun rank: rank 0 prints
        return 0
    if args.save_predictions is not None:
        print(f"predictions: {args.save_predictions}")
    _print_done(done.output, done.report)
    if done.skipped:
        shown = ", ".join(done.skipped[:5])
        print(f"{PROG}: {len(done.skipped)} image(s) skipped (no prediction): {shown}",
              file=sys.stderr)  # fmt: skip
        return EXIT_PARTIAL
    return 0


def _run_scores(args: argparse.Namespace) -> int:
    """``scores CSV``: the complexity analysis of any per-image metric (no model, no labels)."""
    from claravid.eval.run import score_metrics

    _check_bins(args)
    done = score_metrics(args.scores, args.output, data=_data_choice(args),
                         report=_report_settings(args), workers=args.workers,
                         overwrite=args.overwrite)  # fmt: skip
    # The bins and groups as report.md has them, less its warning lines: printed once, below.
    assert done.report is not None  # only a torchrun rank other than 0 has none
    text = done.text.split("## Correlations")[0].rstrip()
    print("\n".join(ln for ln in text.splitlines() if not ln.startswith("**Warning:**")))
    for message in done.report["uncertainty"]["warnings"]:
        print(f"{PROG}: warning: {message}", file=sys.stderr)
    print(f"\nreport: {done.output / 'report.md'} ({done.output / REPORT} and plots beside)")
    return 0


#: The subcommands: each one's parser and what it runs.
SUBCOMMANDS: dict[str, tuple[Callable[[], argparse.ArgumentParser], Callable[..., int]]] = {
    "merge": (build_merge_parser, _run_merge),
    "compare": (build_compare_parser, _run_compare),
    "scores": (build_scores_parser, _run_scores),
}


def main(argv: list[str] | None = None) -> int:
    """``claravid-eval`` (evaluate a model or label maps), ``claravid-eval merge``,
    ``claravid-eval compare`` and ``claravid-eval scores``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SUBCOMMANDS:
        build, run = SUBCOMMANDS[argv[0]]
        return run_cli(PROG, run, build(), argv[1:])
    return run_cli(PROG, _run_evaluation, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

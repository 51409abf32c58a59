"""``claravid-eval``: mIoU per delentropy bin, correlations and a readable report, from any model.

::

    claravid-eval --checkpoint runs/exp/best.pt --split val --output runs/exp/report
    claravid-eval --onnx model.onnx --data /data/claravid --palette uavid --output rep
    claravid-eval --predictions preds/ --data /data/claravid --palette uavid --output rep
    claravid-eval --predictions preds/ --data /data/claravid --tiles 630 --output rep  # + tiles
    claravid-eval --merge part0/ part1/ --output all/            # job-array parts -> one report
    claravid-eval --merge rep/ --edges 4,4.5,5,5.5 --output rep-fixed   # re-bin, no model
    claravid-eval --compare a/report.json b/report.json --output cmp/   # gaps with intervals
    claravid-eval --scores psnr.csv --data /data/uavid --dataset uavid --split test \
        --group-by sequence --measures delent,glcment,pixent --output psnr-rep   # any metric
    torchrun --nproc_per_node=8 -m claravid.eval --checkpoint best.pt --output rep   # many GPUs

Exit 0 on success, 1 when some images were skipped (``--allow-missing``; listed), 2 for a
user's mistake (one line; ``--debug`` shows the traceback).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.units import CLUSTER_UNITS, DATASETS, GROUP_BY
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
    add_window_flags,
    add_workers_flag,
    non_negative_int,
    positive_int,
    run_cli,
)
from claravid.models.backbones.specs import NAMED_STATISTICS
from claravid.models.export.runtime import PROVIDERS

PROG = "claravid-eval"
SOURCES = ("checkpoint", "onnx", "predictions", "merge", "compare", "scores")


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-eval`` arguments (also ``python -m claravid.eval``)."""
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Evaluate semantic segmentation per scene-complexity (delentropy) bin.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("::", 1)[1].split("Exit 0")[0],
    )
    src = p.add_argument_group("what to evaluate (exactly one)")
    add_checkpoint_flag(src)
    src.add_argument("--onnx", type=Path, help="ONNX model (claravid-export), run by onnxruntime")
    src.add_argument(
        "--predictions", type=Path, metavar="DIR", help="saved label maps DIR/<key>.png"
    )
    src.add_argument(
        "--merge", nargs="+", type=Path, metavar="REPORT", help="report folders to merge/re-bin"
    )
    src.add_argument(
        "--compare", nargs="+", type=Path, metavar="REPORT", help="reports to show side by side"
    )
    src.add_argument(
        "--scores", type=Path, metavar="CSV", help="per-image metrics (path + numeric columns)"
    )
    data = p.add_argument_group(
        "data", "Unset, the root, split, palette and selection are the checkpoint's."
    )
    add_data_flag(data)
    # Choices shown, checked by DataChoice (the Python API's check and message).
    data.add_argument(
        "--dataset", metavar=_choices(DATASETS), help="kind of data (default claravid)"
    )
    data.add_argument("--split", help="train, val, test or all (default val)")
    data.add_argument("--palette", help="palette name or YAML (default: the checkpoint's)")
    data.add_argument("--masks", type=Path, help="label folder mirroring --data (folder only)")
    add_selection_flags(data)
    infer = p.add_argument_group("inference")
    add_window_flags(infer)
    add_statistics_flag(infer, NAMED_STATISTICS)
    add_device_flag(infer)
    add_precision_flag(infer)
    infer.add_argument(
        "--provider", metavar=_choices(PROVIDERS), help="ONNX Runtime provider (--onnx)"
    )
    rep = p.add_argument_group("report", "-o/--output is the report folder (--compare: the "
                               "comparison's).")  # fmt: skip
    add_output_flag(rep)
    rep.add_argument("--bins", type=positive_int, help="quantile bins of delentropy (default 3)")
    rep.add_argument("--edges", help="fixed delentropy edges e1,e2,... instead of --bins")
    rep.add_argument(
        "--group-by",
        metavar=_choices(GROUP_BY),
        help="rows per mission, viewpoint, UAVid sequence or folder",
    )
    rep.add_argument("--measures", help="delent,glcment,pixent (default delent)")
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
    rep.add_argument("--save-predictions", type=Path, metavar="DIR", help="write label maps")
    rep.add_argument("--allow-missing", action="store_true", help="skip images w/o prediction")
    add_workers_flag(rep, "complexity and image decoding")
    rep.add_argument("--overwrite", action="store_true", help="replace a foreign output folder")
    add_progress_flag(rep)
    _add_uncertainty(p)
    add_debug_flag(p)
    return p


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


def _check_args(args: argparse.Namespace) -> str:
    given = [name for name in SOURCES if getattr(args, name) is not None]
    if len(given) != 1:
        which = " and ".join(f"--{g}" for g in given) if given else "none"
        raise UsageError(
            f"give exactly one of --checkpoint, --onnx, --predictions, --merge, --compare, "
            f"--scores (got {which})"
        )
    if args.bins is not None and args.edges is not None:
        raise UsageError("give --bins or --edges, not both")
    source = given[0]
    _refuse_idle_options(args, source)
    from claravid.infra.precision import flag_precision

    args.precision = flag_precision(args.precision, pytorch=source == "checkpoint")
    # The settings check themselves as they are made, with the messages the Python API gives
    # (one validation for both): a mistake stops here, before any work.
    args.settings = {"data": _data_choice(args), "inference": _inference(args),
                     "report": _report_settings(args)}  # fmt: skip
    if source != "compare" and args.output is None:
        raise UsageError("--output is required: the folder the report is written to")
    return source


#: Options that change nothing in a mode: given there, they are a user's misunderstanding.
_MODEL_ONLY = (
    "window",
    "stride",
    "scale",
    "batch_size",
    "device",
    "precision",
    "statistics",
    "save_predictions",
)
_DATA = ("data", "dataset", "split", "palette", "masks", "allow_missing", *SELECTION)
#: The measures beyond mIoU: --name and --no-name (None: not given).
QUALITY_FLAGS = ("boundary", "calibration", "consistency")
IDLE = {
    "compare": (*_MODEL_ONLY, *_DATA, "bins", "edges", "group_by", "measures", "tiles",
                "hardest", "provider", "workers", *QUALITY_FLAGS),
    "merge": (*_MODEL_ONLY, *_DATA, "measures", "tiles", "hardest", "provider", "workers",
              *QUALITY_FLAGS),
    # --scores reads images only: no labels (--masks), no label palette (--palette).
    "scores": (*_MODEL_ONLY, "allow_missing", "tiles", "hardest", "provider", "masks", "palette",
               *QUALITY_FLAGS),
    "checkpoint": ("provider",),
    # Label maps are read, not predicted: no precision (an ONNX file is refused it below).
    "predictions": ("provider", "precision", "statistics"),
}  # fmt: skip


def _refuse_idle_options(args: argparse.Namespace, source: str) -> None:
    """Refuse an option that would silently do nothing with this source."""
    for name in IDLE.get(source, ()):
        value = getattr(args, name)
        # 0 or False is a flag's default, except --no-boundary and the like (None is theirs).
        if value is None or (value in (0, False) and name not in QUALITY_FLAGS):
            continue
        flag = ("--" if value is not False else "--no-") + name.replace("_", "-")
        what = " (the reports carry their own measures)" if name in QUALITY_FLAGS else ""
        raise UsageError(f"{flag} does nothing with --{source}{what}; drop it")


def _data_choice(args: argparse.Namespace) -> DataChoice:
    return DataChoice(
        root=args.data,
        dataset=args.dataset,
        split=args.split,
        palette=args.palette,
        masks=args.masks,
        # --missions/--altitude/--direction as given: DataChoice splits them into lists.
        selection={n: getattr(args, n) for n in SELECTION if getattr(args, n) is not None},
    )


def _inference(args: argparse.Namespace) -> InferenceSettings:
    return InferenceSettings(window=args.window, stride=args.stride, scale=args.scale,
                             batch_size=args.batch_size, device=args.device,
                             precision=args.precision, provider=args.provider,
                             statistics=args.statistics)  # fmt: skip


def _report_settings(args: argparse.Namespace) -> ReportSettings:
    intervals = Bootstrap(resamples=args.bootstrap, level=args.ci_level, seed=args.seed)
    return ReportSettings(bins=args.bins or 3, edges=args.edges, group_by=args.group_by,
                          measures=args.measures or "delent", tiles=args.tiles,
                          hardest=4 if args.hardest is None else args.hardest,
                          bootstrap=intervals, cluster=args.cluster, boundary=args.boundary,
                          calibration=args.calibration,
                          consistency=args.consistency)  # fmt: skip


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

    report = args.settings["report"]
    print(compare(args.compare, args.output, report.bootstrap, report.cluster,
                  overwrite=args.overwrite))  # fmt: skip
    if args.output is not None:
        print(f"comparison: {args.output / 'compare.md'} and {args.output / 'compare.png'}")
    return 0


def _run_merge(args: argparse.Namespace) -> int:
    from claravid.eval.reports import merge

    done = merge(args.merge, args.output, args.settings["report"], overwrite=args.overwrite)
    assert done.report is not None  # only a torchrun rank other than 0 has none
    _print_done(done.output, done.report)
    return 0


def _run_evaluation(args: argparse.Namespace, source_kind: str) -> int:
    from claravid.eval.run import evaluate

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
    """``--scores CSV``: the complexity analysis of any per-image metric (no model, no labels)."""
    from claravid.eval.run import score_metrics

    done = score_metrics(args.scores, args.output, data=args.settings["data"],
                         report=args.settings["report"], workers=args.workers,
                         overwrite=args.overwrite)  # fmt: skip
    # The bins and groups as report.md has them, less its warning lines: printed once, below.
    assert done.report is not None  # only a torchrun rank other than 0 has none
    text = done.text.split("## Correlations")[0].rstrip()
    print("\n".join(ln for ln in text.splitlines() if not ln.startswith("**Warning:**")))
    for message in done.report["uncertainty"]["warnings"]:
        print(f"{PROG}: warning: {message}", file=sys.stderr)
    print(f"\nreport: {done.output / 'report.md'} ({done.output / REPORT} and plots beside)")
    return 0


def run(args: argparse.Namespace) -> int:
    """Dispatch on the source: evaluate, merge/re-bin, or compare."""
    source = _check_args(args)
    if source == "compare":
        return _run_compare(args)
    if source == "scores":
        return _run_scores(args)
    if source == "merge":
        return _run_merge(args)
    return _run_evaluation(args, source)


def main(argv: list[str] | None = None) -> int:
    """``claravid-eval``."""
    return run_cli(PROG, run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

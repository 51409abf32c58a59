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

import numpy as np

from claravid.cli import (
    EXIT_PARTIAL,
    UsageError,
    add_debug_flag,
    add_progress_flag,
    add_workers_flag,
    check_device,
    check_output_dir,
    non_negative_int,
    positive_int,
    run_cli,
    window_size,
)
from claravid.eval.analysis.bins import parse_edges
from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.measures import parse_measures
from claravid.eval.analysis.units import CLUSTER_UNITS, DATASETS, GROUP_BY, check_unit
from claravid.eval.report.files import REPORT
from claravid.models.onnx_runtime import PROVIDERS

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
    src.add_argument("--checkpoint", type=Path, help="PyTorch checkpoint (models.save_checkpoint)")
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
    data = p.add_argument_group("data")
    data.add_argument("--data", type=Path, help="dataset root (default: the checkpoint's)")
    data.add_argument("--dataset", choices=DATASETS, help="kind of data (default claravid)")
    data.add_argument("--split", help="train, val, test or all (default val)")
    data.add_argument("--palette", help="palette name or YAML (default: the checkpoint's)")
    data.add_argument("--masks", type=Path, help="label folder mirroring --data (folder only)")
    data.add_argument(
        "--missions", help="ClaraVid missions, e.g. rural_1,urban_2 (default: the checkpoint's)"
    )
    data.add_argument(
        "--altitude", help="ClaraVid altitudes low,mid,high (default: the checkpoint's)"
    )
    data.add_argument("--direction", help="ClaraVid directions h,v (default: the checkpoint's)")
    infer = p.add_argument_group("inference")
    infer.add_argument("--window", type=window_size, metavar="WxH",
                       help="window, width x height or N for N x N (default 630)")  # fmt: skip
    infer.add_argument("--stride", type=window_size, metavar="WxH",
                       help="window step, WxH or N (default 2/3 of the window)")  # fmt: skip
    infer.add_argument("--scale", type=float, help="resize images first (default 1; paper 0.5)")
    infer.add_argument(
        "--batch-size", type=positive_int, help="windows per forward pass (default 4)"
    )
    infer.add_argument("--device", help="cpu or cuda (default: cuda when available)")
    infer.add_argument(
        "--precision",
        help="PyTorch model: fp32 or bf16 autocast (default: fp32 on CPU, bf16/fp16 on CUDA)",
    )
    infer.add_argument("--no-amp", action="store_true", help="deprecated: --precision fp32")
    infer.add_argument("--provider", choices=PROVIDERS, help="ONNX Runtime provider (--onnx)")
    rep = p.add_argument_group("report")
    rep.add_argument("--output", "-o", type=Path, help="report folder")
    rep.add_argument("--bins", type=positive_int, help="quantile bins of delentropy (default 3)")
    rep.add_argument("--edges", help="fixed delentropy edges e1,e2,... instead of --bins")
    rep.add_argument(
        "--group-by", choices=GROUP_BY, help="rows per mission, viewpoint, UAVid sequence or folder"
    )
    rep.add_argument("--measures", help="delent,glcment,pixent (default delent)")
    rep.add_argument(
        "--tiles",
        type=positive_int,
        metavar="T",
        help="also bin tiles of about T px by their own delentropy (e.g. 630)",
    )
    rep.add_argument(
        "--hardest", type=non_negative_int, default=4, help="overlays of the K hardest images"
    )
    rep.add_argument("--save-predictions", type=Path, metavar="DIR", help="write label maps")
    rep.add_argument("--allow-missing", action="store_true", help="skip images w/o prediction")
    add_workers_flag(rep, "complexity and image decoding")
    rep.add_argument("--overwrite", action="store_true", help="replace a foreign output folder")
    add_progress_flag(rep)
    _add_uncertainty(p)
    add_debug_flag(p)
    return p


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


def _check_uncertainty(args: argparse.Namespace) -> None:
    """Fail on bad interval settings before any work (exit 2, one line)."""
    if args.bootstrap < 0:
        raise UsageError(
            f"--bootstrap must be >= 0 (0 switches intervals off), got {args.bootstrap}"
        )
    if not 0 < args.ci_level < 1:
        raise UsageError(f"--ci-level must be between 0 and 1 (e.g. 0.95), got {args.ci_level}")
    if args.cluster is not None and args.cluster not in CLUSTER_UNITS:
        raise UsageError(
            f"unknown --cluster {args.cluster!r}; use one of {', '.join(CLUSTER_UNITS)}"
        )
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")


def bootstrap_settings(
    args: argparse.Namespace, attributes: dict[str, list[str]], default: str
) -> Bootstrap:
    """The interval settings of the command line, its ``--cluster`` checked against the units
    images with these ``attributes`` carry; ``default`` when ``--cluster`` is not given."""
    cluster = check_unit(attributes, args.cluster or default)
    return Bootstrap(resamples=args.bootstrap, level=args.ci_level, seed=args.seed, cluster=cluster)


def data_bootstrap(args: argparse.Namespace, data: Any) -> Bootstrap:
    """:func:`bootstrap_settings` for opened data (an ``EvalData`` of ``open_data``)."""
    from claravid.eval.analysis.units import default_cluster

    return bootstrap_settings(args, data.attributes, default_cluster(data.name, data.attributes))


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
    if args.bins is not None and args.bins < 1:
        raise UsageError(f"--bins must be at least 1, got {args.bins}")
    if args.edges is not None:
        args.edges = parse_edges(args.edges)
    if args.tiles is not None and args.tiles < 2:
        raise UsageError(f"--tiles must be at least 2 pixels (e.g. 630), got {args.tiles}")
    _check_uncertainty(args)
    source = given[0]
    _refuse_idle_options(args, source)
    args.measures = parse_measures(args.measures or "delent")
    from claravid.precision import flag_precision

    args.precision = flag_precision(args.precision, args.no_amp, pytorch=source == "checkpoint")
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
    "no_amp",
    "save_predictions",
)
_SELECTION = ("missions", "altitude", "direction")
_DATA = ("data", "dataset", "split", "palette", "masks", "allow_missing", *_SELECTION)
IDLE = {
    "compare": (*_MODEL_ONLY, *_DATA, "bins", "edges", "group_by", "measures", "tiles"),
    "merge": (*_MODEL_ONLY, *_DATA, "measures", "tiles"),
    "scores": (*_MODEL_ONLY, "allow_missing", "tiles"),
}


def _refuse_idle_options(args: argparse.Namespace, source: str) -> None:
    """Refuse an option that would silently do nothing with this source."""
    for name in IDLE.get(source, ()):
        if getattr(args, name) not in (None, False):
            flag = "--" + name.replace("_", "-")
            raise UsageError(f"{flag} does nothing with --{source}; drop it")


def _warn_outside_edges(report: dict[str, Any], result: Any) -> None:
    """Say when fixed --edges leave images in no bin (the report counts them only)."""
    outside = report["source"].get("binning", {}).get("outside") or []
    if outside:
        import warnings

        values = np.asarray(result.complexity["delent"], dtype=float)
        values = values[np.isfinite(values)]
        span = f"{values.min():.2f}..{values.max():.2f}" if values.size else "n/a"
        warnings.warn(
            f"{len(outside)} of {len(result.paths)} image(s) fall outside --edges (delentropy "
            f"of the images: {span}): they are in no bin",
            UserWarning,
            stacklevel=1,
        )


def _print_done(out: Path, report: dict[str, Any]) -> None:
    from claravid.eval.report.markdown import bin_table

    print(bin_table(report))
    for message in (report.get("uncertainty") or {}).get("warnings", []):
        print(f"{PROG}: warning: {message}", file=sys.stderr)
    print(f"\nreport: {out / 'report.md'} ({out / 'report.json'}, plots and confusions beside)")


def _run_compare(args: argparse.Namespace) -> int:
    from claravid.eval.report.compare import compare_reports

    if args.output is not None:
        check_output_dir(args.output, marker="compare.md", overwrite=args.overwrite)
    settings = Bootstrap(resamples=args.bootstrap, level=args.ci_level, seed=args.seed)
    text, warnings = compare_reports(args.compare, args.output, settings, args.cluster)
    import warnings as py_warnings

    for message in warnings:
        py_warnings.warn(message, UserWarning, stacklevel=1)
    print(text)
    if args.output is not None:
        print(f"comparison: {args.output / 'compare.md'} and {args.output / 'compare.png'}")
    return 0


def _run_merge(args: argparse.Namespace) -> int:
    from claravid.eval.analysis.table import merge_results
    from claravid.eval.report.build import build_report
    from claravid.eval.report.files import load_result
    from claravid.eval.report.folder import write_outputs

    check_output_dir(args.output, marker=REPORT, overwrite=args.overwrite)
    parts = [load_result(p) for p in args.merge]
    _warn_different_runs(parts, args.merge)
    result = merge_results(parts, [str(p) for p in args.merge])
    _warn_dropped_tiles(parts, result, args.merge)
    _check_bins(args, len(result.paths))
    intervals = bootstrap_settings(args, result.attributes, result.default_cluster())
    report = build_report(
        result, bins=args.bins or 3, edges=args.edges, group_by=args.group_by, bootstrap=intervals
    )
    _warn_outside_edges(report, result)
    write_outputs(args.output, report, result)
    _print_done(args.output, report)
    return 0


def _warn_different_runs(parts: list[Any], names: list[Path]) -> None:
    """Job-array parts share one model and one data selection; say when they do not."""
    import warnings

    for key, what in (("path", "model"), ("split", "split"), ("data", "data root")):
        seen = {str(p.source.get(key)) for p in parts if p.source.get(key) is not None}
        if key == "split":  # split files are how job-array parts shard a split: fine
            seen &= {"train", "val", "test", "all"}
        if len(seen) > 1:
            warnings.warn(
                f"merging reports of different {what}s ({', '.join(sorted(seen))}): the merged "
                "numbers mix them",
                UserWarning,
                stacklevel=1,
            )


def _warn_dropped_tiles(parts: list[Any], merged: Any, names: list[Path]) -> None:
    """Tiles merge only when every part has tiles of one size; say when some are dropped."""
    if merged.tiles is None and any(p.tiles is not None for p in parts):
        import warnings

        sizes = [f"{n}: {p.tiles.size if p.tiles is not None else 'none'}"
                 for p, n in zip(parts, names, strict=True)]  # fmt: skip
        warnings.warn(
            "the merged report has no tiles: the parts' tile sizes differ or some have none "
            f"({'; '.join(sizes)}); evaluate every part with the same --tiles",
            UserWarning,
            stacklevel=1,
        )


def _check_bins(args: argparse.Namespace, n: int) -> None:
    if args.edges is None and (args.bins or 3) > n:
        raise UsageError(f"{args.bins or 3} bins for {n} images: use --bins {n} or fewer")


def selection_flags(args: argparse.Namespace, dataset: str) -> dict[str, list[str]]:
    """``--missions``/``--altitude``/``--direction`` as lists (they replace the checkpoint's)."""
    given = {k: getattr(args, k) for k in _SELECTION if getattr(args, k) is not None}
    if given and dataset != "claravid":
        flag = "--" + next(iter(given))
        raise UsageError(
            f"{flag} selects ClaraVid frames; it does nothing with --dataset {dataset}"
        )
    out = {}
    for name, text in given.items():
        values = [v.strip() for v in text.split(",") if v.strip()]
        if not values:
            raise UsageError(f"--{name} is empty; give e.g. --{name} {_EXAMPLE[name]}")
        out[name] = values
    return out


_EXAMPLE = {"missions": "rural_1,urban_2", "altitude": "low,mid", "direction": "h"}


def _resolve_data(args: argparse.Namespace, defaults: dict[str, Any]) -> dict[str, Any]:
    """Command line first, then what the checkpoint recorded, then the defaults."""
    root = args.data or defaults.get("data")
    if root is None:
        hint = "" if args.checkpoint is None else " (the checkpoint does not record its data)"
        raise UsageError(f"--data is required: the dataset root to evaluate on{hint}")
    dataset = args.dataset or defaults.get("dataset") or "claravid"
    if dataset not in DATASETS:
        dataset = "claravid"
    if args.masks is not None and dataset != "folder":
        raise UsageError(f"--masks does nothing with --dataset {dataset}; drop it")
    selection = {}
    if dataset == "claravid" and defaults.get("dataset", "claravid") == "claravid":
        # ClaraVid as in training: the same selection and split settings, so --split val is
        # exactly the frames training held out.
        selection = {k: defaults[k] for k in ("missions", "altitude", "direction",
                                              "split_config") if k in defaults}  # fmt: skip
    selection.update(selection_flags(args, dataset))
    return {
        "root": Path(root),
        "dataset": dataset,
        "split": args.split or defaults.get("split") or "val",
        "palette": args.palette or defaults.get("palette"),
        "masks": args.masks,
        "selection": selection,
    }


def _run_evaluation(args: argparse.Namespace, source_kind: str) -> int:
    import torch

    from claravid import distributed
    from claravid.eval.inference.collect import collect
    from claravid.eval.inference.data import open_data
    from claravid.eval.inference.hardest import hardest_items
    from claravid.eval.inference.label_maps import MARKER, predictions_defaults, write_marker
    from claravid.eval.inference.sources import load_source, resolve_settings
    from claravid.eval.report.build import build_report
    from claravid.eval.report.folder import write_outputs
    from claravid.precision import autocast_dtype, precision_name

    check_device(args.device)  # one line, not CUDA's traceback
    info = distributed.init_distributed(args.device)
    main_rank = info.is_main
    check_output_dir(args.output, marker=REPORT, overwrite=args.overwrite)
    if args.save_predictions is not None:
        if source_kind == "predictions":
            raise UsageError("--save-predictions needs a model (--checkpoint or --onnx)")
        check_output_dir(
            args.save_predictions,
            marker=MARKER,
            overwrite=args.overwrite,
            what="--save-predictions",
        )
    # Every rank has checked the untouched folders; only now may any rank write to them.
    distributed.barrier()
    model = None
    if source_kind in ("checkpoint", "onnx"):
        threads = torch.get_num_threads() if info.device.type == "cpu" else None
        model = load_source(
            args.checkpoint, args.onnx, device=info.device, threads=threads, provider=args.provider
        )
        settings = resolve_settings(
            model, window=args.window, stride=args.stride, scale=args.scale,
            batch_size=args.batch_size, palette=args.palette, precision=args.precision,
        )  # fmt: skip
    if model is None:  # saved label maps: the palette their predictions.json names
        defaults = predictions_defaults(args.predictions, args.palette)
    spec = _resolve_data(args, model.defaults if model else defaults)
    try:
        data = open_data(
            spec["root"],
            dataset=spec["dataset"],
            split=spec["split"],
            palette=spec["palette"],
            masks=spec["masks"],
            selection=spec["selection"],
        )
    except FileNotFoundError as exc:
        if args.data is not None or model is None or "data" not in model.defaults:
            raise
        raise UsageError(  # the data moved since training: say where the path came from
            f"{exc} (that path comes from the checkpoint {model.path}; pass --data to give the "
            "data's new place)"
        ) from None
    num_classes = data.palette.num_classes
    if model is not None and model.num_classes not in (None, num_classes):
        raise UsageError(
            f"the model predicts {model.num_classes} classes but palette {data.palette.name} has "
            f"{num_classes}; pass the palette it was trained with (--palette)"
        )
    if args.group_by is not None:
        data.groups(args.group_by)  # fails now, not after the inference
    _check_bins(args, len(data))
    intervals = data_bootstrap(args, data)
    window = None
    source: dict[str, Any] = {"kind": source_kind}
    if model is not None:
        window = settings.window
        source["path"] = str(model.path)
        source["window"] = {
            "size": list(window.size),
            "stride": list(window.stride),
            "scale": window.scale,
        }
        if model.kind == "onnx":  # runs as exported: the file's metadata, None when foreign
            source["precision"] = getattr(model.model, "precision", None)
        else:
            source["precision"] = precision_name(autocast_dtype(window.precision, info.device))
        source["settings"] = settings.describe()
    else:
        source["predictions"] = str(args.predictions)
    source.update(data.describe)
    source["measures"] = list(args.measures)
    if args.tiles is not None:
        source["tiles"] = args.tiles

    collected = collect(
        data,
        model=model,
        predictions=args.predictions,
        window=window,
        measures=args.measures,
        workers=args.workers,
        device=info.device,
        save_predictions=args.save_predictions,
        allow_missing=args.allow_missing,
        hardest=args.hardest,
        tile_size=args.tiles,
        progress=main_rank and not args.no_progress,
        source=source,
    )
    if not main_rank:
        distributed.barrier()  # rank 0 writes the report meanwhile
        return 0
    try:
        result = collected.result
        _check_bins(args, len(result.paths))
        report = build_report(
            result,
            bins=args.bins or 3,
            edges=args.edges,
            group_by=args.group_by,
            bootstrap=intervals,
        )
        _warn_outside_edges(report, result)
        dirs = [d for d in (args.predictions, args.save_predictions) if d is not None]
        items = hardest_items(result, data, args.hardest, collected.hardest, dirs)
        write_outputs(args.output, report, result, items, data.palette.colors)
        if args.save_predictions is not None:
            write_marker(args.save_predictions, data.palette, source)
            print(f"predictions: {args.save_predictions}")
        _print_done(args.output, report)
    finally:
        distributed.barrier()  # the other ranks wait for the report, even when it failed
    if collected.skipped:
        shown = ", ".join(collected.skipped[:5])
        print(
            f"{PROG}: {len(collected.skipped)} image(s) skipped (no prediction): {shown}",
            file=sys.stderr,
        )
        return EXIT_PARTIAL
    return 0


def _run_scores(args: argparse.Namespace) -> int:
    """``--scores CSV``: the complexity analysis of any per-image metric (no model, no labels)."""
    from claravid.eval.analysis.metric_bins import metric_report
    from claravid.eval.analysis.units import unit_labels
    from claravid.eval.inference.complexity_job import ComplexityJob
    from claravid.eval.inference.data import open_data
    from claravid.eval.inference.metric_csv import match_images, read_metrics_csv
    from claravid.eval.report.folder import write_metric_outputs

    if args.data is None:
        raise UsageError("--scores needs --data: the dataset root the CSV's paths belong to")
    check_output_dir(args.output, marker=REPORT, overwrite=args.overwrite)
    dataset = args.dataset or "claravid"
    csv_paths, metrics = read_metrics_csv(args.scores, args.data)
    data = open_data(
        args.data,
        dataset=dataset,
        split=args.split or ("all" if dataset == "claravid" else "val"),
        palette=args.palette,
        masks=args.masks,
        selection=selection_flags(args, dataset),
        labels=False,
    )
    if args.group_by is not None:
        data.groups(args.group_by)
    settings = data_bootstrap(args, data)
    order = match_images(csv_paths, data.paths, args.scores)
    paths = [data.paths[i] for i in order]
    if args.edges is None and (args.bins or 3) > len(paths):
        raise UsageError(f"{args.bins or 3} bins for {len(paths)} images: use --bins {len(paths)}")
    attributes = {a: [v[i] for i in order] for a, v in data.attributes.items()}
    clusters = unit_labels(paths, attributes, settings.cluster)
    groups = None
    if args.group_by is not None:
        groups = {}
        for pos, label in enumerate(attributes[args.group_by]):
            groups.setdefault(label, []).append(pos)
        groups = dict(sorted(groups.items()))
    values = ComplexityJob(paths, args.measures, threads=max(1, args.workers)).result()
    complexity = {m: np.asarray(values[m], dtype=np.float64) for m in args.measures}
    report = metric_report(paths, metrics, complexity, clusters, settings,
                           bins=args.bins or 3, edges=args.edges, groups=groups)  # fmt: skip
    binning = {**report.pop("binning", {}), "group_by": args.group_by}
    report["source"] = {"kind": "scores", "scores": str(args.scores), **data.describe,
                        "measures": list(args.measures), "binning": binning}  # fmt: skip
    out = Path(args.output)
    text = write_metric_outputs(out, report)
    print(text.split("## Correlations")[0].rstrip())
    for message in report["uncertainty"]["warnings"]:
        print(f"{PROG}: warning: {message}", file=sys.stderr)
    print(f"\nreport: {out / 'report.md'} ({out / REPORT} and plots beside)")
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

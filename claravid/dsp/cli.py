"""``claravid-dsp``: per-image complexity and the scene profile of a collection of images.

Examples::

    claravid-dsp --data /data/ClaraVid/003_urban_1 --pattern 'left_rgb/**/*.jpg' --plot urban_1.png
    claravid-dsp --data frames.txt --metric glcment --workers 8 --output glcm.json
    claravid-dsp --data complexity_results.json --plot profile.png   # official JSON: no recompute
    claravid-dsp --data /data/big --pattern '**/*.jpg' --shard $SLURM_ARRAY_TASK_ID/16 -o part.json
    claravid-dsp --merge part_*.json --output all.json --plot all.png
    claravid-dsp --compare claravid.json uavid.json

Exit status: 0 on success (unreadable images are listed under "errors"), 1 when no image could be
read, 2 for bad arguments or an input that names no image.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from claravid.dsp.collection import (
    ProfileRun,
    find_images,
    load_results,
    merge_runs,
    profile_images,
)
from claravid.dsp.measures import METRICS
from claravid.dsp.metrics import check_blur_ksize
from claravid.infra.cli import (
    UsageError,
    add_data_flag,
    add_debug_flag,
    add_output_flag,
    add_progress_flag,
    add_workers_flag,
    run_cli,
)
from claravid.infra.files import check_output_file
from claravid.infra.shards import parse_shard, select_shard

DEFAULT_OUTPUT = "complexity_results.json"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for documentation and tests)."""
    parser = argparse.ArgumentParser(
        prog="claravid-dsp",
        description="Delentropic Scene Profile (and GLCM / pixel entropy baselines) of a "
        "collection of images, with the official ClaraVid values. --data is a folder (searched "
        "with --pattern), a text file of image paths, or a results JSON (official or ours) to "
        f"profile and plot again without recomputing; -o/--output is the results JSON (default "
        f"{DEFAULT_OUTPUT} when computing).",
        epilog="Exit status: 0 ok, 1 no image could be read, 2 bad arguments or no input images.",
    )
    add_data_flag(parser)
    parser.add_argument(
        "--pattern", default="*.jpg", help="glob inside a folder; '**' recurses (default *.jpg)"
    )
    parser.add_argument("--metric", default="delent", choices=METRICS, help="default delent")
    add_workers_flag(parser, "the measurement")
    add_output_flag(parser, metavar="JSON")
    parser.add_argument("--plot", type=Path, help="save the profile plot here (PNG)")
    parser.add_argument("--no-blur", action="store_true", help="skip the Gaussian blur")
    parser.add_argument(
        "--blur-ksize", type=int, default=3, help="odd Gaussian kernel size (default 3)"
    )
    parser.add_argument(
        "--shard", help="k/n: measure only every n-th sorted image from the k-th (0-based)"
    )
    parser.add_argument("--no-cache", action="store_true", help="neither read nor write the cache")
    add_progress_flag(parser)
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an --output file that is not a results JSON",
    )
    add_debug_flag(parser)
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument(
        "--merge", nargs="+", type=Path, metavar="JSON", help="join shard outputs into one profile"
    )
    mode.add_argument(
        "--compare", nargs="+", type=Path, metavar="JSON", help="table of profiles side by side"
    )
    return parser


def _summary(run: ProfileRun) -> str:
    p = run.profile
    bad = f" ({len(run.errors)} unreadable, left out)" if run.errors else ""
    return (
        f"{run.metric} over {len(run.results)} images{bad}: mu={p.mu:.4f} sigma={p.sigma:.4f} "
        f"alpha={p.alpha:.4f} beta={p.beta:.4f} a={p.a:.4f} b={p.b:.4f}"
    )


def _check_outputs(args: argparse.Namespace, output: Path | None) -> None:
    """Fail before the computation when an output cannot be written (or is not ours to replace)."""
    if output is not None:
        check_output_file(output, what="--output")
        if output.is_file() and not args.overwrite:
            try:
                with warnings.catch_warnings():  # only its kind matters, not its profile
                    warnings.simplefilter("ignore")
                    load_results(output)
            except (OSError, ValueError):
                raise UsageError(
                    f"--output {output} exists and is not a complexity results file; choose "
                    "another name or pass --overwrite to replace it"
                ) from None
    if args.plot is not None:
        check_output_file(args.plot, what="--plot")
        from claravid.dsp.plot import plot_format

        plot_format(args.plot)


def _run(args: argparse.Namespace) -> int:
    if args.compare:
        from claravid.dsp.compare import compare_table

        if args.data is not None:
            raise UsageError("--compare takes JSON files only; drop --data")
        if args.output is not None or args.plot is not None:
            raise UsageError("--compare prints a table; --output and --plot do not apply")
        runs = [load_results(p) for p in args.compare]
        print(compare_table(runs, [str(p) for p in args.compare]))
        return 0

    output = args.output
    json_input = (
        args.data is not None and args.data.is_file() and args.data.suffix.lower() == ".json"
    )
    if args.merge:
        if args.data is not None:
            raise UsageError("--merge takes JSON files only; drop --data")
        output = output or Path(DEFAULT_OUTPUT)
    elif args.data is None:
        raise UsageError(
            "give --data (a folder, a list file or a results JSON), --merge or --compare"
        )
    elif json_input:
        if args.shard is not None:
            raise UsageError("--shard applies to a folder or a list file, not to a results JSON")
    else:
        # Cheap argument errors first, before a long directory walk.
        # An empty --shard ($UNSET) is an error, not "no shard".
        k, n = parse_shard(args.shard) if args.shard is not None else (0, 1)
        if not args.no_blur:
            check_blur_ksize(args.blur_ksize)
        if args.shard is not None:
            output = output or Path(f"complexity_results.shard-{k}-of-{n}.json")
        output = output or Path(DEFAULT_OUTPUT)
    _check_outputs(args, output)

    if args.merge:
        run = merge_runs([load_results(p) for p in args.merge])
    elif args.data is None:  # refused above, before the output checks
        raise UsageError("give --data (a folder, a list file or a results JSON) or --merge")
    elif json_input:
        run = load_results(args.data)
    else:
        paths = find_images(args.data, args.pattern)
        shard = None
        if args.shard is not None:
            shard = {"index": k, "count": n, "num_candidates": len(paths)}
            paths = select_shard(paths, k, n)
        run = profile_images(
            paths,
            args.metric,
            blur=not args.no_blur,
            ksize=args.blur_ksize,
            workers=args.workers,
            cache=not args.no_cache,
            progress=not args.no_progress,
        )
        run.shard = shard

    for err in run.errors:
        print(f"skipped {err.image_path}: {err.error}", file=sys.stderr)
    print(_summary(run))
    if output is not None:
        print(f"wrote {run.save(output)}")
    if args.plot is not None:
        from claravid.dsp.plot import plot_profile

        plot_profile(run.values, run.profile, args.plot, metric=run.metric)
        print(f"wrote {args.plot}")
    if not run.results and (run.errors or not run.shard):
        print("claravid-dsp: error: no image could be read; see the reasons above", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``claravid-dsp``; returns the exit status."""
    return run_cli("claravid-dsp", _run, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())

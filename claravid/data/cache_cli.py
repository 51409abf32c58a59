"""``claravid-cache``: prepare the label cache of a ClaraVid selection up front, in parallel.

Examples::

    claravid-cache --data /data/ClaraVid --workers 8
    claravid-cache --data /data/ClaraVid --missions urban_1,urban_2 --altitude low -o /fast/c
    claravid-cache --data /data/ClaraVid --shard $SLURM_ARRAY_TASK_ID/16 --no-progress

Label codes are palette-independent, so one preparation serves every palette: a frame's codes
carry the dynamic flag whenever the frame has a dynamic mask, the entries every
``ClaraVidSegmentation`` with a label cache reads (the frames are chosen by the same rule,
:meth:`ClaraVidSegmentation.prepare_label_cache`). Running it again builds only what is missing
or invalid.

``--data``, ``-o/--output``, ``--missions``, ``--altitude`` and ``--direction`` are the flags
every command shares (one comma-separated list each for the selection).

Exit status: 0 ok, 1 some frames' label files could not be read or their entry location
refused the write (listed), 2 bad arguments, a root that is not ClaraVid, or a cache folder
that cannot take any entry (full disk, read-only).
"""

from __future__ import annotations

import argparse
import sys

from claravid.infra.cli import (
    EXIT_OK,
    EXIT_PARTIAL,
    UsageError,
    add_data_flag,
    add_debug_flag,
    add_output_flag,
    add_progress_flag,
    add_selection_flags,
    add_workers_flag,
    run_cli,
    selection_names,
)

PROG = "claravid-cache"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for documentation and tests)."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Prepare the label-code cache of a ClaraVid selection (tiled TIFFs read by "
        "window), so training never decodes a panoptic PNG. --data is the ClaraVid root; "
        "-o/--output the cache root (default $CLARAVID_CACHE, else ~/.cache/claravid; the "
        "label_cache= folder of ClaraVidSegmentation); the selection defaults to every frame.",
        epilog="Exit status: 0 ok, 1 some label files could not be read or entries written "
        "(listed), 2 bad arguments, no ClaraVid root, or a cache that cannot be written.",
    )
    add_data_flag(parser, required=True)
    add_selection_flags(parser)
    add_workers_flag(parser, "building the cache")
    parser.add_argument(
        "--shard", help="k/n: prepare only every n-th frame from the k-th (0-based)"
    )
    add_output_flag(parser)
    add_progress_flag(parser)
    add_debug_flag(parser)
    return parser


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"  # unreachable; keeps type checkers content


def _run(args: argparse.Namespace) -> int:
    from claravid.data.label_cache import CacheWriteError
    from claravid.data.segmentation import ClaraVidSegmentation
    from claravid.infra.shards import parse_shard

    # Cheap errors first. An empty --shard (an unset variable) is an error, not "every frame".
    shard = parse_shard(args.shard) if args.shard is not None else (0, 1)
    selection = {name: selection_names(name, getattr(args, name))
                 for name in ("missions", "altitude", "direction")
                 if getattr(args, name) is not None}  # fmt: skip
    if args.output is not None and args.output.exists() and not args.output.is_dir():
        raise UsageError(f"--output {args.output} is a file; give a folder")
    dataset = ClaraVidSegmentation(
        args.data,
        split="all",
        missions=selection.get("missions"),
        altitude=selection.get("altitude"),
        direction=selection.get("direction"),
        label_cache=args.output or True,
    )
    try:
        summary = dataset.prepare_label_cache(
            workers=args.workers, progress=not args.no_progress, shard=shard
        )
    except CacheWriteError as exc:
        where = "CLARAVID_CACHE=DIR or --output DIR" if args.output is None else "--output"
        raise UsageError(
            f"{exc.reason}; {exc.written} entries were written before it, none is half-written; "
            f"free some space or choose a writable folder ({where})"
        ) from None
    cache = dataset.label_cache
    assert cache is not None  # label_cache= was given
    failures = summary.failed + summary.unwritten
    order = {str(f.paths["pan_seg"]): i for i, f in enumerate(dataset.frames)}
    for pan, reason in sorted(failures, key=lambda failure: order[failure[0]]):
        print(f"skipped {pan}: {reason}", file=sys.stderr)
    part = f" (shard {shard[0]}/{shard[1]} of {len(dataset.frames)})" if args.shard else ""
    if summary.built == 0 and not failures:
        print(f"nothing to do: all {summary.frames} frames{part} are already cached")
    else:
        print(
            f"built {summary.built} entries ({_size(summary.bytes_built)}) in "
            f"{summary.seconds:.1f} s; {summary.skipped} already cached; "
            f"{len(summary.failed)} unreadable; {len(summary.unwritten)} not writable{part}"
        )
    print(
        f"cache: {summary.built + summary.skipped} frames, {_size(summary.bytes_total)} in total, "
        f"{_size(summary.bytes_per_frame)} per frame, in {cache.directory}"
    )
    return EXIT_PARTIAL if failures else EXIT_OK


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``claravid-cache``; returns the exit status."""
    return run_cli(PROG, _run, build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())

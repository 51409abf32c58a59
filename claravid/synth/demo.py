"""``claravid-demo``: the toolkit end to end on a generated ClaraVid-format scene.

Writes the demo scene to ``OUT/data`` (once), prints frames per mission and viewpoint and
the pixel share of each class, saves a sheet of samples to ``OUT/samples.png``, and the
Delentropic Scene Profile of each mission to ``OUT/dsp_<mission>.json`` and
``OUT/dsp_profiles.png``.
"""

from __future__ import annotations

import argparse
import shutil
from collections import Counter
from pathlib import Path

from matplotlib.figure import Figure

from claravid.data.plot import save_sample_sheet
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.dsp import plot_profile, profile_images
from claravid.dsp.plot import save_figure
from claravid.infra.cli import (
    UsageError,
    add_debug_flag,
    add_output_flag,
    add_progress_flag,
    add_workers_flag,
    non_negative_int,
    parse_size,
    positive_int,
    run_cli,
)
from claravid.infra.files import check_output_dir
from claravid.io.layout import ALTITUDES, DIRECTIONS, MISSIONS, MODALITIES, viewpoint_folder
from claravid.synth import MARKER as SYNTH_MARKER
from claravid.synth import synthesize

#: Left in OUT: the folder is the demo's, so a later run may write there again.
MARKER = ".claravid-demo"
#: Written in OUT/data once the scene is complete, with the settings it was made with.
STAMP = ".demo-complete"


def prepare_data(
    out: Path,
    size: tuple[int, int],
    frames: int,
    seed: int,
    overwrite: bool = False,
    progress: bool = True,
) -> Path:
    """Generate the demo scene unless a complete one with these settings is there.

    ``OUT/data`` is the demo's own (checked by :func:`check_demo_folder`): a scene of other
    settings, or one whose generation was interrupted, is removed first, so no frame of an
    earlier run is left among the new ones.
    """
    data = out / "data"
    stamp = data / STAMP
    settings = f"size={size} frames={frames} seed={seed}"
    if stamp.is_file() and stamp.read_text() == settings:
        print(f"demo scene: reusing {data}")
        return data
    if data.is_dir() and ((data / SYNTH_MARKER).is_file() or stamp.is_file()):
        shutil.rmtree(data)
    print(f"demo scene: generating {data} ({settings})")
    synthesize(
        data,
        seed=seed,
        frames_per_viewpoint=frames,
        size=size,
        progress=progress,
        overwrite=overwrite,
    )
    stamp.write_text(settings)
    return data


def check_demo_folder(out: Path, overwrite: bool = False) -> Path:
    """Refuse an output folder with files the demo did not write (unless ``overwrite``).

    The demo writes ``samples.png``, ``dsp_*.json`` and ``dsp_profiles.png`` into ``OUT`` and
    leaves :data:`MARKER` there; a ``data/`` folder with the demo's stamp (older demo runs)
    counts as ours too.
    """
    ours = (out / "data" / STAMP).is_file()
    return check_output_dir(out, marker=MARKER, overwrite=overwrite or ours)


def print_summary(dataset: ClaraVidSegmentation, progress: bool = True) -> None:
    """Frames per mission and viewpoint, then the pixel share of each class."""
    counts = Counter((f.mission, f.viewpoint) for f in dataset.frames)
    views = [viewpoint_folder(a, d) for a in ALTITUDES for d in DIRECTIONS]
    print(f"\n{len(dataset)} frames\n")
    print(f"{'mission':<14}" + "".join(f"{v:>13}" for v in views) + f"{'total':>8}")
    for mission in MISSIONS:
        row = [counts.get((mission, v), 0) for v in views]
        if any(row):
            print(f"{mission:<14}" + "".join(f"{n:>13}" for n in row) + f"{sum(row):>8}")
    pixels = dataset.class_frequencies(progress=progress)
    total = max(int(pixels.sum()), 1)
    print(f"\npixel share per class ({dataset.palette.name} palette)")
    for name, count in sorted(zip(dataset.classes, pixels, strict=True), key=lambda t: -t[1]):
        print(f"  {name:<16}{100 * count / total:6.2f} %")


def print_profiles(data: Path, out: Path, workers: int) -> None:
    """Profile each mission's RGB frames (delentropy), print the table and save the plots."""
    runs = {}
    for mission, folder in MISSIONS.items():
        paths = sorted(MODALITIES["rgb"].folder_in(data / folder).glob("*/*.jpg"))
        if paths:
            runs[mission] = profile_images(paths, workers=workers)
            runs[mission].save(out / f"dsp_{mission}.json")
    print("\nDelentropic Scene Profile per mission (delentropy, bits)")
    print(f"  {'mission':<14}{'images':>7}{'μ':>8}{'σ':>8}{'α':>8}{'β':>8}")
    for mission, result in runs.items():
        p = result.profile
        print(f"  {mission:<14}{p.n:>7}{p.mu:>8.3f}{p.sigma:>8.3f}{p.alpha:>8.2f}{p.beta:>8.2f}")
    fig = Figure(figsize=(16, 7), layout="constrained")
    axes = fig.subplots(2, (len(runs) + 1) // 2, squeeze=False).ravel()
    for ax, (mission, result) in zip(axes, runs.items(), strict=False):
        plot_profile(result.values, result.profile, ax=ax, title=mission)
    path = save_figure(fig, out / "dsp_profiles.png", dpi=80)
    print(f"profile plots: {path}")


def run(
    out: Path,
    size: tuple[int, int],
    frames: int,
    seed: int,
    workers: int = 0,
    overwrite: bool = False,
    progress: bool = True,
) -> None:
    """Generate (or reuse) the scene, summarise it, save the sample sheet and the profiles."""
    if workers < 0:
        raise UsageError(f"--workers must be >= 0 (0: in this process), got {workers}")
    check_demo_folder(out, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER).write_text("Written by claravid-demo.\n")
    data = prepare_data(out, size, frames, seed, overwrite, progress)
    dataset = ClaraVidSegmentation(data, split="all", palette="claravid")
    print_summary(dataset, progress)
    # One frame per mission, in the UAVid taxonomy (moving and static cars apart).
    uavid = ClaraVidSegmentation(data, split="all", palette="uavid", altitude="mid", direction="h")
    firsts: dict[str, int] = {}
    for index, frame in enumerate(uavid.frames):
        firsts.setdefault(frame.mission, index)
    samples = [uavid[i] for i in firsts.values()]
    sheet = save_sample_sheet(samples, uavid.palette, out / "samples.png")
    print(f"\nsample sheet (UAVid palette): {sheet}")
    print_profiles(data, out, workers)
    print(f"\nresults in {out}")


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-demo`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="claravid-demo",
        description="The toolkit end to end on a generated ClaraVid-format scene, written into "
        "the -o/--output folder (e.g. runs/demo).",
    )
    add_output_flag(parser, required=True)
    parser.add_argument("--size", type=parse_size, default=(640, 480), metavar="WxH",
                        help="image size, width x height (default 640x480)")  # fmt: skip
    parser.add_argument("--frames-per-viewpoint", type=positive_int, default=3)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    add_workers_flag(parser, "the scene profiles")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="write into a non-empty folder the demo did not write",
    )
    add_progress_flag(parser)
    add_debug_flag(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``claravid-demo``; returns the exit status."""

    def _run(args: argparse.Namespace) -> None:
        run(
            args.output,
            args.size,
            args.frames_per_viewpoint,
            args.seed,
            args.workers,
            args.overwrite,
            progress=not args.no_progress,
        )

    return run_cli("claravid-demo", _run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

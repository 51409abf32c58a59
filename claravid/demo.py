"""``claravid-demo``: the toolkit end to end on a generated ClaraVid-format scene.

Writes the demo scene to ``OUT/data`` (once), prints frames per mission and viewpoint and
the pixel share of each class, and saves a sheet of samples to ``OUT/samples.png``.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path

from claravid.layout import ALTITUDES, DIRECTIONS, MISSIONS, viewpoint_folder
from claravid.plot import save_sample_sheet
from claravid.segmentation import ClaraVidSegmentation
from claravid.synth import parse_size, positive_int, synthesize


def prepare_data(out: Path, size: tuple[int, int], frames: int, seed: int) -> Path:
    """Generate the demo scene unless a complete one with these settings is there."""
    data = out / "data"
    stamp = data / ".demo-complete"
    settings = f"size={size} frames={frames} seed={seed}"
    if stamp.is_file() and stamp.read_text() == settings:
        print(f"demo scene: reusing {data}")
        return data
    print(f"demo scene: generating {data} ({settings})")
    synthesize(data, seed=seed, frames_per_viewpoint=frames, size=size, progress=True)
    stamp.write_text(settings)
    return data


def print_summary(dataset: ClaraVidSegmentation) -> None:
    """Frames per mission and viewpoint, then the pixel share of each class."""
    counts = Counter((f.mission, f.viewpoint) for f in dataset.frames)
    views = [viewpoint_folder(a, d) for a in ALTITUDES for d in DIRECTIONS]
    print(f"\n{len(dataset)} frames\n")
    print(f"{'mission':<14}" + "".join(f"{v:>13}" for v in views) + f"{'total':>8}")
    for mission in MISSIONS:
        row = [counts.get((mission, v), 0) for v in views]
        if any(row):
            print(f"{mission:<14}" + "".join(f"{n:>13}" for n in row) + f"{sum(row):>8}")
    pixels = dataset.class_frequencies()
    total = max(int(pixels.sum()), 1)
    print(f"\npixel share per class ({dataset.palette.name} palette)")
    for name, count in sorted(zip(dataset.classes, pixels, strict=True), key=lambda t: -t[1]):
        print(f"  {name:<16}{100 * count / total:6.2f} %")


def run(out: Path, size: tuple[int, int], frames: int, seed: int) -> None:
    """Generate (or reuse) the scene, summarise it and save the sample sheet."""
    data = prepare_data(out, size, frames, seed)
    dataset = ClaraVidSegmentation(data, split="all", palette="claravid")
    print_summary(dataset)
    # One frame per mission, in the UAVid taxonomy (moving and static cars apart).
    uavid = ClaraVidSegmentation(data, split="all", palette="uavid", altitude="mid", direction="h")
    firsts = {}
    for index, frame in enumerate(uavid.frames):
        firsts.setdefault(frame.mission, index)
    samples = [uavid[i] for i in firsts.values()]
    sheet = save_sample_sheet(samples, uavid.palette, out / "samples.png")
    print(f"\nsample sheet (UAVid palette): {sheet}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="claravid-demo", description=__doc__.split("\n")[0])
    parser.add_argument("out", type=Path, help="output folder, e.g. runs/demo")
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="WIDTHxHEIGHT")
    parser.add_argument("--frames-per-viewpoint", type=positive_int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    run(args.out, args.size, args.frames_per_viewpoint, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

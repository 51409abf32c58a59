"""Synthetic ClaraVid: procedurally drawn aerial scenes written in the exact on-disk format.

``claravid-synth OUT --seed S --frames-per-viewpoint N --size WxH [--missions ...]`` (or
:func:`synthesize`) writes ``OUT/<mission>/<modality>/<altitude>_<direction>/<stem>.<ext>``
for every file modality. Each mission is a top-down world (roads with lane lines, buildings
with shadows, trees, fields, water, vehicles and pedestrians, some of them moving, plus the
mission's props) seen from a flight grid, from sparse rural and forest scenes to dense
towers, so scene-complexity bins mean something. Output is byte-identical for a seed.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from claravid import modalities
from claravid.layout import (
    ALTITUDES,
    DIRECTIONS,
    FOCAL_PX,
    IMAGE_SIZE,
    MISSIONS,
    canonical_mission,
    frame_file,
    viewpoint_folder,
)
from claravid.synth.render import flight_poses, render
from claravid.synth.scenery import build_world

__all__ = ["main", "parse_size", "positive_int", "synthesize"]


def _ground_resolution(size: tuple[int, int]) -> float:
    """Metres per world pixel: a bit finer than the closest view's pixels, within [0.2, 1] m."""
    focal = FOCAL_PX * size[0] / IMAGE_SIZE[0]
    return float(np.clip(0.75 * 50.0 / focal, 0.2, 1.0))


def _choose(values: Sequence[str] | None, valid: dict[str, str], what: str) -> list[str]:
    if values is None:
        return list(valid)
    if isinstance(values, str) or not values:
        raise ValueError(f"{what} must be a non-empty list of keys from {', '.join(valid)}")
    bad = [v for v in values if v not in valid]
    if bad:
        raise ValueError(f"unknown {what} {bad[0]!r}; valid {what}: {', '.join(valid)}")
    return list(dict.fromkeys(values))


def _check(size: object, frames_per_viewpoint: object) -> tuple[int, int]:
    if (
        not isinstance(size, (tuple, list))
        or len(size) != 2
        or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in size)
    ):
        raise ValueError(f"size must be a (width, height) pair of integers, got {size!r}")
    if min(size) <= 0:
        raise ValueError(f"size must be positive, got {size[0]}x{size[1]}")
    if (
        not isinstance(frames_per_viewpoint, (int, np.integer))
        or isinstance(frames_per_viewpoint, bool)
        or frames_per_viewpoint <= 0
    ):
        raise ValueError(
            f"frames_per_viewpoint must be a positive integer, got {frames_per_viewpoint!r}"
        )
    return int(size[0]), int(size[1])


def synthesize(
    out: str | Path,
    *,
    seed: int = 0,
    frames_per_viewpoint: int = 4,
    size: tuple[int, int] = IMAGE_SIZE,
    missions: Sequence[str] | None = None,
    altitudes: Sequence[str] | None = None,
    directions: Sequence[str] | None = None,
    progress: bool = False,
) -> Path:
    """Write a synthetic ClaraVid tree and return its root.

    Args:
        out: root folder to write (created; existing files of the same names are replaced).
        seed: scene seed; the same seed and arguments give byte-identical files.
        frames_per_viewpoint: frames (stems ``000000``, ``000001``...) per altitude×direction.
        size: (width, height) of every image; intrinsics are ClaraVid's scaled to it.
        missions: SDK keys, aliases or folder names; default all eight.
        altitudes: ``low``, ``mid``, ``high``; default all.
        directions: ``h``, ``v``; default both.
        progress: show a tqdm progress bar over frames.

    Raises:
        ValueError: a bad size, frame count, mission, altitude or direction.
    """
    width, height = _check(size, frames_per_viewpoint)
    if missions is not None and (isinstance(missions, str) or not missions):
        raise ValueError(f"missions must be a non-empty list of keys from {', '.join(MISSIONS)}")
    keys = list(dict.fromkeys(canonical_mission(m) for m in (missions or MISSIONS)))
    alts = _choose(altitudes, ALTITUDES, "altitudes")
    dirs = _choose(directions, DIRECTIONS, "directions")
    root = Path(out)
    total = len(keys) * len(alts) * len(dirs) * frames_per_viewpoint
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="claravid-synth", unit="frame")
    res = _ground_resolution((width, height))
    mission_index = {k: i for i, k in enumerate(MISSIONS)}
    try:
        for key in keys:
            m = mission_index[key]
            world = build_world(key, seed, res)
            for alt in alts:
                for direction in dirs:
                    # Seeded by the keys' fixed indices, so a subset renders the same frames.
                    a_i, d_i = list(ALTITUDES).index(alt), list(DIRECTIONS).index(direction)
                    rng = np.random.default_rng([seed, m, 2, a_i, d_i])
                    poses = flight_poses(frames_per_viewpoint, alt, direction, rng)
                    for i, pose in enumerate(poses):
                        noise = np.random.default_rng([seed, m, 3, a_i, d_i, i])
                        frame = render(world, pose, (width, height), noise)
                        _write(
                            root / MISSIONS[key],
                            viewpoint_folder(alt, direction),
                            f"{i:06d}",
                            frame,
                            pose,
                        )
                        if bar is not None:
                            bar.update()
    finally:
        if bar is not None:
            bar.close()
    return root


def _write(mission_dir: Path, viewpoint: str, stem: str, frame, pose: np.ndarray) -> None:
    def path(key: str) -> Path:
        return frame_file(mission_dir, viewpoint, stem, key)

    modalities.write_rgb(path("rgb"), frame.rgb)
    modalities.write_depth(path("depth"), frame.depth)
    modalities.write_seg_color(path("seg_color"), frame.seg_color)
    modalities.write_pan_seg(path("pan_seg"), frame.semantic, frame.instance)
    modalities.write_dynamic_mask(path("dynamic_mask"), frame.dynamic_mask)
    modalities.write_extrinsics(path("extrinsics"), pose)


def parse_size(text: str) -> tuple[int, int]:
    """argparse type for ``WIDTHxHEIGHT``."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 640x480, got {text!r}")
    width, height = int(parts[0]), int(parts[1])
    if width <= 0 or height <= 0:
        raise argparse.ArgumentTypeError(f"width and height must be positive, got {text!r}")
    return width, height


def positive_int(text: str) -> int:
    """argparse type for a positive integer."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def main(argv: list[str] | None = None) -> int:
    """Command line: ``claravid-synth OUT --seed S --frames-per-viewpoint N --size WxH ...``."""
    parser = argparse.ArgumentParser(
        prog="claravid-synth", description="Write a synthetic ClaraVid dataset tree."
    )
    parser.add_argument("out", type=Path, help="root folder to write")
    parser.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    parser.add_argument("--frames-per-viewpoint", type=positive_int, default=4, metavar="N",
                        help="frames per altitude and direction (default 4)")  # fmt: skip
    parser.add_argument("--size", type=parse_size, default=IMAGE_SIZE, metavar="WxH",
                        help="image size (default the native 4032x3024)")  # fmt: skip
    parser.add_argument("--missions", nargs="+", metavar="MISSION",
                        help=f"default all: {' '.join(MISSIONS)}")  # fmt: skip
    parser.add_argument("--altitudes", nargs="+", choices=list(ALTITUDES), help="default all")
    parser.add_argument("--directions", nargs="+", choices=list(DIRECTIONS), help="default both")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        missions = [canonical_mission(m) for m in args.missions] if args.missions else None
    except ValueError as error:
        parser.error(str(error))
    root = synthesize(
        args.out,
        seed=args.seed,
        frames_per_viewpoint=args.frames_per_viewpoint,
        size=args.size,
        missions=missions,
        altitudes=args.altitudes,
        directions=args.directions,
        progress=not args.quiet,
    )
    print(root, file=sys.stdout)
    return 0

"""Synthetic ClaraVid: procedurally drawn aerial scenes written in the exact on-disk format.

``claravid-synth -o OUT --seed S --frames-per-viewpoint N --size WxH [--missions a,b] [--altitude
low,mid] [--direction h]`` (or :func:`synthesize`) writes
``OUT/<mission>/<modality>/<altitude>_<direction>/<stem>.<ext>`` for every file modality, and a
:data:`MARKER` file at ``OUT`` so that it never writes over a tree it did not make. Each mission
is a top-down world (roads with lane lines, buildings with shadows, trees, fields, water,
vehicles and pedestrians, some of them moving, plus the mission's props) seen from a flight
grid, from sparse rural and forest scenes to dense towers, so scene-complexity bins mean
something. Output is byte-identical for a seed.
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from claravid.infra.cli import (
    add_debug_flag,
    add_output_flag,
    add_progress_flag,
    add_selection_flags,
    add_workers_flag,
    non_negative_int,
    parse_size,
    positive_int,
    run_cli,
    selection_names,
)
from claravid.io import modalities
from claravid.io.layout import (
    ALTITUDES,
    DIRECTIONS,
    FOCAL_PX,
    IMAGE_SIZE,
    MISSIONS,
    canonical_mission,
    frame_file,
    viewpoint_folder,
)
from claravid.synth.render import Frame, flight_poses, render
from claravid.synth.scenery import build_world
from claravid.synth.world import World

__all__ = [
    "MARKER",
    "check_output_root",
    "main",
    "parse_size",
    "synthesize",
]

#: File the generator leaves at the root of every tree it writes: running it again over its own
#: output is fine, over anything else (a real ClaraVid download) it needs ``overwrite``.
MARKER = ".claravid-synth"
# Fixed text (no date, no settings): trees of one seed stay byte-identical.
_MARKER_TEXT = "Written by claravid-synth: synthetic data, safe to regenerate.\n"


def _ground_resolution(size: tuple[int, int]) -> float:
    """Metres per world pixel: a bit finer than the closest view's pixels, within [0.2, 1] m."""
    focal = FOCAL_PX * size[0] / IMAGE_SIZE[0]
    return float(np.clip(0.75 * 50.0 / focal, 0.2, 1.0))


def _choose(values: str | Sequence[str] | None, valid: dict[str, str], what: str) -> list[str]:
    # Not claravid.data.index._choose: the datasets' validator takes a single key as a one-key list
    # (same here) but lets an empty list select nothing, while a generator asked to write nothing
    # is a mistake, so an empty selection is an error here; duplicates are dropped so no frame
    # is rendered twice.
    if values is None:
        return list(valid)
    if isinstance(values, str):
        values = [values]
    if not values:
        raise ValueError(f"{what} must name at least one of {', '.join(valid)} (or be None: all)")
    bad = [v for v in values if v not in valid]
    if bad:
        raise ValueError(f"unknown {what} {bad[0]!r}; valid: {', '.join(valid)}")
    return list(dict.fromkeys(values))


def _check(size: object, frames_per_viewpoint: object, seed: object) -> tuple[int, int]:
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
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(size[0]), int(size[1])


def check_output_root(out: str | Path, overwrite: bool = False) -> Path:
    """Refuse to write into a folder that holds files the generator did not write.

    A folder is ours when it holds :data:`MARKER` (written before the first frame, so an
    interrupted run is ours too). Anything else that is not empty, e.g. a real ClaraVid
    download, is refused unless ``overwrite``: frames of the same names would be replaced.

    Raises:
        NotADirectoryError: ``out`` is a file.
        FileExistsError: ``out`` is a non-empty folder without the marker and not ``overwrite``.
    """
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"output {root} is a file; give a folder to write the tree in")
    ours = (root / MARKER).is_file()
    if root.is_dir() and not ours and not overwrite and any(root.iterdir()):
        raise FileExistsError(
            f"output {root} is not empty and was not written by claravid-synth (no {MARKER}); "
            "its files would be replaced: choose a new folder, or pass --overwrite "
            "(overwrite=True) if you mean it"
        )
    return root


def synthesize(
    out: str | Path,
    *,
    seed: int = 0,
    frames_per_viewpoint: int = 4,
    size: tuple[int, int] = IMAGE_SIZE,
    missions: str | Sequence[str] | None = None,
    altitude: str | Sequence[str] | None = None,
    direction: str | Sequence[str] | None = None,
    progress: bool = False,
    overwrite: bool = False,
    workers: int = 0,
) -> Path:
    """Write a synthetic ClaraVid tree and return its root.

    Args:
        out: root folder to write (created). A folder the generator wrote before (it holds
            :data:`MARKER`) is written again, files of the same names replaced; any other
            non-empty folder is refused unless ``overwrite``.
        seed: scene seed (>= 0); the same seed and arguments give byte-identical files.
        frames_per_viewpoint: frames (stems ``000000``, ``000001``...) per altitude×direction.
        size: (width, height) of every image; intrinsics are ClaraVid's scaled to it.
        missions: SDK keys, aliases or folder names (one or a list); default all eight.
        altitude: ``low``, ``mid``, ``high`` (one or a list); default all, as in the datasets.
        direction: ``h``, ``v`` (one or a list); default both.
        progress: show a tqdm progress bar over frames.
        overwrite: write into a non-empty folder the generator did not write.
        workers: render the viewpoints (altitude×direction of a mission) in this many worker
            processes; 0 renders them here. Every frame has its own seed: the files are the
            same either way.

    Raises:
        ValueError: a bad size, frame count, seed, mission, altitude or direction.
        FileExistsError: ``out`` holds files not written by the generator (see ``overwrite``).
        NotADirectoryError: ``out`` is a file.
    """
    width, height = _check(size, frames_per_viewpoint, seed)
    if isinstance(missions, str):
        missions = [missions]
    if missions is not None and not missions:
        raise ValueError(f"missions must name at least one of {', '.join(MISSIONS)} (or be None)")
    keys = list(dict.fromkeys(canonical_mission(m) for m in (missions or MISSIONS)))
    alts = _choose(altitude, ALTITUDES, "altitude")
    dirs = _choose(direction, DIRECTIONS, "direction")
    root = check_output_root(out, overwrite)
    root.mkdir(parents=True, exist_ok=True)
    (root / MARKER).write_text(_MARKER_TEXT, encoding="utf-8")
    total = len(keys) * len(alts) * len(dirs) * frames_per_viewpoint
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc="claravid-synth", unit="frame")
    res = _ground_resolution((width, height))
    jobs = [(root, key, seed, res, alt, direction, frames_per_viewpoint, (width, height))
            for key in keys for alt in alts for direction in dirs]  # fmt: skip
    try:
        if workers > 0 and len(jobs) > 1:
            import concurrent.futures as cf

            with cf.ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
                for done in cf.as_completed([pool.submit(_render_viewpoint, *j) for j in jobs]):
                    count = done.result()  # a worker's error is raised here
                    if bar is not None:
                        bar.update(count)
        else:
            for job in jobs:
                count = _render_viewpoint(*job)
                if bar is not None:
                    bar.update(count)
    finally:
        if bar is not None:
            bar.close()
    return root


@functools.lru_cache(maxsize=1)
def _world(key: str, seed: int, res: float) -> World:
    """One mission's world, kept for its next viewpoint (in this process or a worker)."""
    return build_world(key, seed, res)


def _render_viewpoint(
    root: Path, key: str, seed: int, res: float, alt: str, direction: str, frames: int,
    size: tuple[int, int],
) -> int:  # fmt: skip
    """Render and write the frames of one altitude×direction of a mission; their count."""
    m = list(MISSIONS).index(key)
    world = _world(key, seed, res)
    # Seeded by the keys' fixed indices, so a subset renders the same frames.
    a_i, d_i = list(ALTITUDES).index(alt), list(DIRECTIONS).index(direction)
    rng = np.random.default_rng([seed, m, 2, a_i, d_i])
    poses = flight_poses(frames, alt, direction, rng)
    for i, pose in enumerate(poses):
        noise = np.random.default_rng([seed, m, 3, a_i, d_i, i])
        frame = render(world, pose, size, noise)
        _write(root / MISSIONS[key], viewpoint_folder(alt, direction), f"{i:06d}", frame, pose)
    return len(poses)


def _write(mission_dir: Path, viewpoint: str, stem: str, frame: Frame, pose: np.ndarray) -> None:
    def path(key: str) -> Path:
        return frame_file(mission_dir, viewpoint, stem, key)

    modalities.write_rgb(path("rgb"), frame.rgb)
    modalities.write_depth(path("depth"), frame.depth)
    modalities.write_seg_color(path("seg_color"), frame.seg_color)
    modalities.write_pan_seg(path("pan_seg"), frame.semantic, frame.instance)
    modalities.write_dynamic_mask(path("dynamic_mask"), frame.dynamic_mask)
    modalities.write_extrinsics(path("extrinsics"), pose)


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-synth`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="claravid-synth",
        description="Write a synthetic ClaraVid dataset tree into the -o/--output folder (every "
        "mission, altitude and direction unless selected).",
        epilog="Exit status: 0 ok; 2 a bad argument or an output folder that is not ours.",
    )
    add_output_flag(parser, required=True)
    parser.add_argument("--seed", type=non_negative_int, default=0, help="scene seed (default 0)")
    parser.add_argument("--frames-per-viewpoint", type=positive_int, default=4, metavar="N",
                        help="frames per altitude and direction (default 4)")  # fmt: skip
    parser.add_argument("--size", type=parse_size, default=IMAGE_SIZE, metavar="WxH",
                        help="image size, width x height (default native 4032x3024)")  # fmt: skip
    add_selection_flags(parser)
    parser.add_argument(
        "--overwrite", action="store_true", help="write into a non-empty folder that is not ours"
    )
    add_workers_flag(parser, "rendering (one viewpoint each at a time)")
    add_progress_flag(parser)
    add_debug_flag(parser)
    return parser


def _run(args: argparse.Namespace) -> int:
    chosen = {name: selection_names(name, getattr(args, name))
              for name in ("missions", "altitude", "direction")
              if getattr(args, name) is not None}  # fmt: skip
    missions = [canonical_mission(m) for m in chosen["missions"]] if "missions" in chosen else None
    root = synthesize(
        args.output,
        seed=args.seed,
        frames_per_viewpoint=args.frames_per_viewpoint,
        size=args.size,
        missions=missions,
        altitude=chosen.get("altitude"),
        direction=chosen.get("direction"),
        progress=not args.no_progress,
        overwrite=args.overwrite,
        workers=args.workers,
    )
    print(root, file=sys.stdout)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command line: ``claravid-synth -o OUT --seed S --frames-per-viewpoint N --size WxH ...``."""
    return run_cli("claravid-synth", _run, build_parser(), argv)

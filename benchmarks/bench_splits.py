"""Speed of the block split at ClaraVid's size against the old dealing and the extrinsics read.

    PYTHONPATH=. python benchmarks/bench_splits.py [--repeat 3]

Takes the camera positions of ``claravid-synth --frames-per-viewpoint 350`` (16,800 frames,
from the generator's own ``flight_poses``), then prints the best of ``--repeat`` runs of:
1. ``assign_blocks`` with 150 m blocks (four per mission: unbalanced missions, so it also
   deals at smaller sizes to suggest one), with 50 m blocks (balanced), and with 20 m blocks;
2. the baseline: the old per-mission cumulative dealing (each block to the split whose
   cumulative target its middle falls in), restated here;
3. what a dataset pays for the split anyway: reading the 16,800 extrinsics JSON files
   (``camera_positions``), written to a temp folder first.
Target: every dealing < 1 s, and below the extrinsics read.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from collections import defaultdict
from pathlib import Path

import numpy as np

from claravid.data.index import Frame
from claravid.data.segmentation import camera_positions
from claravid.data.splits import SplitBalanceWarning, SplitConfig, assign_blocks
from claravid.io import modalities
from claravid.io.layout import ALTITUDES, DIRECTIONS, MISSIONS, frame_file
from claravid.synth.render import flight_poses


def synth_frames(per_viewpoint: int = 350) -> tuple[list[Frame], list[np.ndarray]]:
    frames, poses = [], []
    for m, mission in enumerate(MISSIONS):
        for a, altitude in enumerate(ALTITUDES):
            for d, direction in enumerate(DIRECTIONS):
                rng = np.random.default_rng([0, m, 2, a, d])  # as claravid.synth seeds it
                for i, pose in enumerate(flight_poses(per_viewpoint, altitude, direction, rng)):
                    frames.append(Frame(mission, altitude, direction, f"{i:06d}", {}))
                    poses.append(pose)
    return frames, poses


def old_dealing(frames: list[Frame], positions: np.ndarray, config: SplitConfig) -> list[str]:
    """The dealing before issue 12 §2 (per mission, block middles against cumulative targets)."""
    blocks = np.floor(positions / config.block_size).astype(int)
    by_mission: dict = defaultdict(lambda: defaultdict(list))
    for i, frame in enumerate(frames):
        by_mission[frame.mission][tuple(blocks[i])].append(i)
    targets = np.cumsum(config.fractions)
    result = [""] * len(frames)
    for mission, mission_blocks in by_mission.items():
        keys = sorted(mission_blocks)
        order = np.random.default_rng([config.seed, list(MISSIONS).index(mission)]).permutation(
            len(keys)
        )
        total, dealt = sum(len(v) for v in mission_blocks.values()), 0
        for rank in order:
            members = mission_blocks[keys[rank]]
            middle = (dealt + len(members) / 2) / total
            split = ("train", "val", "test")[min(int(np.searchsorted(targets, middle, "right")), 2)]
            for i in members:
                result[i] = split
            dealt += len(members)
    return result


def best_of(repeat: int, fn) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    frames, poses = synth_frames()
    positions = np.array([p[:2, 3] for p in poses])
    print(f"{len(frames)} frames")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for frame, pose in zip(frames, poses, strict=True):
            path = frame_file(
                root / MISSIONS[frame.mission], frame.viewpoint, frame.stem, "extrinsics"
            )
            modalities.write_extrinsics(path, pose)
        read = best_of(1, lambda: camera_positions(root, frames))
    base = best_of(args.repeat, lambda: old_dealing(frames, positions, SplitConfig()))
    print(f"read 16,800 extrinsics files (camera_positions): {read:7.3f} s")
    print(f"old dealing, 150 m (baseline):                  {base:7.3f} s")
    warnings.simplefilter("ignore", SplitBalanceWarning)
    for size in (150.0, 50.0, 20.0):
        config = SplitConfig(block_size=size)
        took = best_of(args.repeat, lambda c=config: assign_blocks(frames, positions, c))
        print(
            f"assign_blocks, {size:5.0f} m blocks:                   {took:7.3f} s  "
            f"({took / base:5.1f}x the old dealing, {took / read:4.2f}x the extrinsics read)"
        )


if __name__ == "__main__":
    main()

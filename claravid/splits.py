"""Train/val/test splits of ClaraVid frames that do not leak.

ClaraVid has no official split, and neighbouring frames overlap heavily, so a random frame
split would put the same ground in train and test. The default split therefore assigns
*spatial blocks* of camera positions: the ground plane of each mission is cut into square
blocks of ``block_size`` metres (camera x, y from the extrinsics), and whole blocks go to
one split, so every altitude and direction over a block lands in the same split. Blocks
are shuffled with ``seed`` and dealt to train/val/test until each split holds its fraction
of the mission's frames. Frames near a block edge still see a little of the neighbouring
block: use a larger ``block_size`` (the footprint of a frame is about 1.5× its altitude
across, 70-110 m) for a stricter split.

Also: a text file listing the frames of a published split, and hold-out by mission.
"""

from __future__ import annotations

import math
import numbers
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from claravid.index import Frame
from claravid.layout import MISSIONS, canonical_mission

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class SplitConfig:
    """How frames are split.

    Attributes:
        block_size: side of the square blocks of camera positions, in metres.
        fractions: target share of each mission's frames in train, val and test; finite,
            non-negative, summing to 1.
        seed: shuffles the blocks; the same seed gives the same split.
        val_missions: missions held out whole as the validation split (a string: one).
        test_missions: missions held out whole as the test split. With any held-out
            mission, every other mission goes whole to train.
    """

    block_size: float = 150.0
    fractions: tuple[float, float, float] = (0.7, 0.15, 0.15)
    seed: int = 0
    val_missions: Sequence[str] | str = field(default_factory=tuple)
    test_missions: Sequence[str] | str = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if not _is_number(self.block_size) or not 0 < self.block_size < math.inf:
            raise ValueError(
                f"block_size must be a positive number of metres, got {self.block_size!r}"
            )
        try:
            fractions = tuple(self.fractions) if not isinstance(self.fractions, str) else ()
        except TypeError:  # a single number
            fractions = ()
        if len(fractions) != 3 or not all(_is_number(f) for f in fractions):
            raise ValueError(
                f"fractions must be three numbers (train, val, test), got {self.fractions!r}"
            )
        if not all(0 <= f < math.inf for f in fractions):  # NaN fails both comparisons
            raise ValueError(f"fractions must be finite and non-negative, got {self.fractions!r}")
        total = math.fsum(fractions)
        # No silent rescaling: (0.8, 0.1, 0.2) is more likely a typo than a wish for 73/9/18 %.
        if not math.isclose(total, 1.0, abs_tol=1e-6):
            raise ValueError(
                f"fractions {self.fractions!r} sum to {total:g}, not 1; give train, val and "
                "test shares that add up to 1, e.g. (0.7, 0.15, 0.15)"
            )
        # A single string is one mission, as in the datasets' `missions` argument.
        val = tuple(map(canonical_mission, _as_tuple(self.val_missions)))
        test = tuple(map(canonical_mission, _as_tuple(self.test_missions)))
        both = set(val) & set(test)
        if both:
            raise ValueError(f"missions {sorted(both)} are held out as both val and test")
        # Frozen: normalised values are set once, here.
        object.__setattr__(self, "fractions", fractions)
        object.__setattr__(self, "val_missions", val)
        object.__setattr__(self, "test_missions", test)


def _is_number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _as_tuple(missions: Sequence[str] | str | None) -> tuple[str, ...]:
    if missions is None:
        return ()
    return (missions,) if isinstance(missions, str) else tuple(missions)


def assign_blocks(frames: Sequence[Frame], positions: np.ndarray, config: SplitConfig) -> list[str]:
    """The split of each frame, from its camera position (N×2 metres) and the config."""
    if config.val_missions or config.test_missions:
        held = {canonical_mission(m): "val" for m in config.val_missions}
        held |= {canonical_mission(m): "test" for m in config.test_missions}
        return [held.get(f.mission, "train") for f in frames]

    blocks = np.floor(np.asarray(positions, dtype=np.float64) / config.block_size).astype(int)
    by_mission: dict[str, dict[tuple[int, int], list[int]]] = defaultdict(lambda: defaultdict(list))
    for i, frame in enumerate(frames):
        by_mission[frame.mission][tuple(blocks[i])].append(i)

    fractions = np.asarray(config.fractions, dtype=np.float64)
    targets = np.cumsum(fractions)
    result = [""] * len(frames)
    for mission, mission_blocks in by_mission.items():
        keys = sorted(mission_blocks)
        order = np.random.default_rng([config.seed, list(MISSIONS).index(mission)]).permutation(
            len(keys)
        )
        total = sum(len(v) for v in mission_blocks.values())
        dealt = 0
        for rank in order:
            members = mission_blocks[keys[rank]]
            # Give the block to the split whose cumulative target the block's middle falls in.
            middle = (dealt + len(members) / 2) / total
            split = SPLITS[min(int(np.searchsorted(targets, middle, side="right")), 2)]
            for i in members:
                result[i] = split
            dealt += len(members)
    return result


def read_split_file(path: str | Path) -> list[str]:
    """Frame keys listed in a split file, one per line; ``#`` starts a comment.

    A line is a frame key ``<mission folder>/<viewpoint>/<stem>`` or the path of any of the
    frame's files relative to the root (``003_urban_1/left_rgb/45deg_low_h/000123.jpg``).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"split file not found: {path}")
    keys = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = Path(line).with_suffix("").parts
        if len(parts) == 4:  # mission / modality / viewpoint / stem
            parts = (parts[0], parts[2], parts[3])
        if len(parts) != 3:
            raise ValueError(
                f"{path}:{number}: {line!r} is not a frame; write <mission folder>/<viewpoint>/"
                "<stem> or a file path relative to the ClaraVid root"
            )
        keys.append("/".join(parts))
    if not keys:
        raise ValueError(
            f"split file {path} lists no frame; write one frame per line "
            "(<mission folder>/<viewpoint>/<stem>)"
        )
    return keys


def select_split(
    frames: Sequence[Frame],
    split: str | Path,
    config: SplitConfig,
    positions: Callable[[], np.ndarray],
) -> list[Frame]:
    """The frames of ``split``: ``train``/``val``/``test``, ``all``, or a split-file path.

    ``positions`` is called only when the block split needs the camera positions.
    """
    if split == "all":
        return list(frames)
    if split in SPLITS:
        assigned = assign_blocks(frames, positions(), config)
        return [f for f, s in zip(frames, assigned, strict=True) if s == split]
    path = Path(split)
    if path.suffix != ".txt" and not path.is_file():
        raise ValueError(
            f"unknown split {str(split)!r}: use 'train', 'val', 'test', 'all' or the path of a "
            "split file listing frames"
        )
    wanted = read_split_file(path)
    by_key = {f.key: f for f in frames}
    missing = [k for k in wanted if k not in by_key]
    if missing:
        raise ValueError(
            f"{len(missing)} frame(s) of split file {path} are not in the selection, e.g. "
            f"{missing[:3]}; check the root, missions and viewpoints you selected"
        )
    return [by_key[k] for k in dict.fromkeys(wanted)]

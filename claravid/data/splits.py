"""Train/val/test splits of ClaraVid frames that do not leak.

ClaraVid has no official split, and neighbouring frames overlap heavily, so a random frame
split would put the same ground in train and test. The default split therefore assigns
*spatial blocks* of camera positions: the ground plane of each mission is cut into square
blocks of ``block_size`` metres (camera x, y from the extrinsics; the grid laid over the
mission's own extent, ``claravid.data.blocks.mission_origins``), and whole blocks go to
one split, so every altitude and direction over a block lands in the same split
(:func:`block_ids` names each frame's block). Frames near a block edge still see a little of
the neighbouring block: use a larger ``block_size`` (the footprint of a frame is about 1.5×
its altitude across, 70-110 m) for a stricter split.

Blocks are dealt over all missions together (``claravid.data.blocks``): the overall shares as
close to ``fractions`` as the block sizes allow, then each mission's own shares as close as
its blocks allow, no open split left empty, the same dealing for the same seed. A mission of
a few blocks cannot hold 70/15/15 % by itself; when a mission's shares end up more than
:data:`TOLERANCE` off the targets, :func:`assign_blocks` warns once
(:class:`SplitBalanceWarning`), naming the missions and the largest block size that
balances them, found by dealing at smaller sizes. :func:`summarize_split` and
:class:`SplitSummary` report the realised shares per mission and overall.

Also: a text file listing the frames of a published split, and hold-out by mission.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import warnings
from collections import Counter, defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from claravid.data.blocks import block_ids, deal_blocks, group_blocks
from claravid.data.index import Frame
from claravid.io.layout import MISSIONS, canonical_mission

__all__ = [
    "SPLITS",
    "SplitBalanceWarning",
    "SplitConfig",
    "SplitConfigError",
    "SplitSummary",
    "assign_blocks",
    "block_ids",
    "make_split_config",
    "read_split_file",
    "select_split",
    "split_summary",
    "suggest_block_size",
    "summarize_split",
]

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class SplitConfig:
    """How frames are split.

    Attributes:
        block_size: side of the square blocks of camera positions, in metres.
        fractions: target share of the frames in train, val and test (overall, and in each
            mission as far as its blocks allow); finite, non-negative, summing to 1.
        seed: orders the dealing of the blocks; the same seed gives the same split.
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
            raise SplitConfigError(
                "block_size", f"must be a positive number of metres, got {self.block_size!r}"
            )
        try:
            fractions = tuple(self.fractions) if not isinstance(self.fractions, str) else ()
        except TypeError:  # a single number
            fractions = ()
        if len(fractions) != 3 or not all(_is_number(f) for f in fractions):
            raise SplitConfigError(
                "fractions", f"must be three numbers (train, val, test), got {self.fractions!r}"
            )
        if not all(0 <= f < math.inf for f in fractions):  # NaN fails both comparisons
            raise SplitConfigError(
                "fractions", f"must be finite and non-negative, got {self.fractions!r}"
            )
        total = math.fsum(fractions)
        # No silent rescaling: (0.8, 0.1, 0.2) is more likely a typo than a wish for 73/9/18 %.
        if not math.isclose(total, 1.0, abs_tol=1e-6):
            raise SplitConfigError(
                "fractions",
                f"{self.fractions!r} sum to {total:g}, not 1; give train, val and test shares "
                "that add up to 1, e.g. (0.7, 0.15, 0.15)",
            )
        # numpy's generators take integers >= 0; a string "1" is refused, not parsed.
        if not isinstance(self.seed, numbers.Integral) or isinstance(self.seed, bool):
            quoted = isinstance(self.seed, str)
            hint = " (a string: write the number without quotes)" if quoted else ""
            raise SplitConfigError("seed", f"must be an integer >= 0, got {self.seed!r}{hint}")
        if self.seed < 0:
            raise SplitConfigError("seed", f"must be an integer >= 0, got {self.seed!r}")
        # A single string is one mission, as in the datasets' `missions` argument.
        val = _missions("val_missions", self.val_missions)
        test = _missions("test_missions", self.test_missions)
        both = set(val) & set(test)
        if both:
            raise SplitConfigError(
                "val_missions",
                f"and test_missions both hold {sorted(both)}: missions held out as both val and "
                "test; hold each out once",
            )
        # Frozen: normalised values are set once, here.
        object.__setattr__(self, "fractions", fractions)
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "val_missions", val)
        object.__setattr__(self, "test_missions", test)


class SplitConfigError(ValueError):
    """A :class:`SplitConfig` value that cannot work; ``setting`` names the field.

    The message starts with the setting as the caller spells it: ``seed`` from
    :class:`SplitConfig` itself, ``split_config.seed`` from :func:`make_split_config` with that
    prefix (the datasets), ``data.split.seed`` from a training config.
    """

    def __init__(self, setting: str, detail: str | None = None, message: str | None = None) -> None:
        if detail is None and message is None:  # the message alone (a rebuilt error)
            super().__init__(setting)
            self.setting: str | None = None
            self.detail: str | None = None
            return
        super().__init__(message or f"{setting} {detail}")
        self.setting = setting
        self.detail = detail


def make_split_config(
    values: SplitConfig | Mapping[str, Any] | None, prefix: str = "split_config."
) -> SplitConfig:
    """A :class:`SplitConfig` from a mapping of its fields; errors name ``prefix + field``.

    Raises:
        SplitConfigError: an unknown key, or a value :class:`SplitConfig` refuses.
    """
    if values is None:
        return SplitConfig()
    if isinstance(values, SplitConfig):
        return values
    if not isinstance(values, Mapping):
        raise SplitConfigError(
            prefix.rstrip("."),
            f"must be a SplitConfig or a dict of its fields, got {type(values).__name__}",
        )
    names = [f.name for f in dataclasses.fields(SplitConfig)]
    unknown = sorted(set(values) - set(names))
    if unknown:
        what = prefix.rstrip(".")
        raise SplitConfigError(
            f"{prefix}{unknown[0]}",
            "is not a split setting",
            f"unknown {what} key(s) {unknown}; valid: {', '.join(names)}",
        )
    try:
        return SplitConfig(**values)
    except SplitConfigError as exc:
        if exc.setting is None:  # rebuilt from its message alone: nothing to prefix
            raise
        raise SplitConfigError(prefix + exc.setting, exc.detail) from None


def _missions(setting: str, missions: Any) -> tuple[str, ...]:
    """Canonical mission keys of a held-out list (a single string is one mission); ``missions``
    is any value a config holds, checked here."""
    if missions is None:
        return ()
    if isinstance(missions, str):
        missions = (missions,)
    try:
        items = tuple(missions)
    except TypeError:
        items = (missions,)
    out = []
    for item in items:
        if not isinstance(item, str):
            raise SplitConfigError(
                setting, f"must be mission names (a string or a list of them), got {missions!r}"
            )
        try:
            out.append(canonical_mission(item))
        except ValueError as exc:
            raise SplitConfigError(setting, f"holds {exc}") from None
    return tuple(out)


def _is_number(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def assign_blocks(frames: Sequence[Frame], positions: np.ndarray, config: SplitConfig) -> list[str]:
    """The split of each frame, from its camera position (N×2 metres) and the config.

    Blocks are dealt by ``claravid.data.blocks.deal_blocks`` (see the module docstring). Warns
    once (:class:`SplitBalanceWarning`) when a mission's shares are more than
    :data:`TOLERANCE` off the targets, naming the missions and the block size that would
    balance them.
    """
    if config.val_missions or config.test_missions:
        held = {canonical_mission(m): "val" for m in config.val_missions}
        held |= {canonical_mission(m): "test" for m in config.test_missions}
        _warn_absent_held_out(frames, held)
        return [held.get(f.mission, "train") for f in frames]
    splits, names = _deal(frames, positions, config)
    summary = split_summary(frames, splits, names, config)
    if frames and summary.off_target():
        # stacklevel 2: every dataset built from one selection warns from the same line, so
        # Python shows the identical message once (train and val sets of one run).
        warnings.warn(
            _balance_message(summary, suggest_block_size(frames, positions, config)),
            SplitBalanceWarning,
            stacklevel=2,
        )
    return splits


def _warn_absent_held_out(frames: Sequence[Frame], held: dict[str, str]) -> None:
    """Warn when a held-out mission has no frame in the selection: its split is left empty.

    A warning, not an error: the other splits are still right (e.g. training on the selected
    missions while the held-out one is not on this machine), and an empty split is refused
    where it is used (no frames to validate or evaluate); the warning says why it is empty.
    """
    present = {f.mission for f in frames}
    absent = [(m, s) for m, s in held.items() if m not in present]
    if frames and absent:
        named = ", ".join(f"{MISSIONS[m]} ({s}_missions)" for m, s in absent)
        chosen = ", ".join(MISSIONS[m] for m in MISSIONS if m in present)
        warnings.warn(
            f"held-out mission(s) {named} have no frame in the selection ({chosen}): "
            f"{' and '.join(sorted({s for _, s in absent}))} holds no frame from them; add "
            "them to the selected missions, or check the root has their folders",
            UserWarning,
            stacklevel=3,
        )


def _deal(
    frames: Sequence[Frame], positions: np.ndarray, config: SplitConfig
) -> tuple[list[str], list[str]]:
    """(split, block id) of each frame under the block split of ``config``."""
    blocks = group_blocks(frames, positions, config.block_size)
    dealt = deal_blocks(blocks.size, blocks.mission, config.fractions, config.seed)
    names = blocks.names()
    of_frame = blocks.of_frame.tolist()
    return [SPLITS[dealt[b]] for b in of_frame], [names[b] for b in of_frame]


class SplitBalanceWarning(UserWarning):
    """A mission's train/val/test shares are far from the targets: its blocks are too few."""


#: How far (a share, 0.10 = 10 percentage points) a mission may be off its targets unwarned.
TOLERANCE: float = 0.10
#: Block sizes (metres) tried, largest first, to suggest one that balances every mission.
CANDIDATE_BLOCK_SIZES: tuple[float, ...] = (150, 120, 100, 80, 75, 60, 50, 40, 30, 25, 20)


@dataclass(frozen=True)
class Shares:
    """Frames and blocks of one mission (or of all) in each split, in ``SPLITS`` order."""

    name: str
    frames: tuple[int, ...]
    blocks: tuple[int, ...]

    @property
    def shares(self) -> tuple[float, ...]:
        """Fraction of the frames in each split (zeros when there are none)."""
        total = sum(self.frames)
        return tuple(n / total if total else 0.0 for n in self.frames)


@dataclass(frozen=True)
class SplitSummary:
    """The realised train/val/test shares of a split, per mission and overall.

    Attributes:
        targets: the fractions asked for.
        block_size: metres; seed: the dealing's seed.
        missions: one row per mission folder, in ClaraVid's order.
        overall: all missions together (``name`` is ``"all"``).
    """

    targets: tuple[float, ...]
    block_size: float
    seed: int
    missions: tuple[Shares, ...]
    overall: Shares

    def off_target(self, tolerance: float = TOLERANCE) -> list[Shares]:
        """Rows (missions, then overall) with a share more than ``tolerance`` off its target."""
        targets = np.asarray(self.targets)
        # 1e-12: a share exactly at the tolerance (a float a hair over) is not off.
        return [
            r
            for r in (*self.missions, self.overall)
            if np.abs(np.asarray(r.shares) - targets).max() > tolerance + 1e-12
        ]

    def table(self) -> str:
        """A fixed-width table: frames, blocks and the % of frames in each split per mission."""
        head = "/".join(SPLITS)
        target = "/".join(f"{100 * t:.0f}" for t in self.targets)
        lines = [
            f"split shares ({self.block_size:g} m blocks, seed {self.seed}; target {head} "
            f"{target} %):",
            f"  {'mission':<20} {'frames':>6} {'blocks':>6}  "
            + " ".join(f"{s:>6}" for s in SPLITS),
        ]
        for row in [*self.missions, self.overall]:
            shares = " ".join(f"{100 * s:6.1f}" for s in row.shares)
            lines.append(f"  {row.name:<20} {sum(row.frames):6d} {sum(row.blocks):6d}  {shares}")
        return "\n".join(lines)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: targets, block size, seed, and frames/blocks/shares per row."""

        def row(r: Shares) -> dict[str, Any]:
            return {
                "frames": dict(zip(SPLITS, r.frames, strict=True)),
                "blocks": dict(zip(SPLITS, r.blocks, strict=True)),
                "shares": dict(zip(SPLITS, r.shares, strict=True)),
            }

        return {
            "targets": dict(zip(SPLITS, self.targets, strict=True)),
            "block_size": self.block_size,
            "seed": self.seed,
            "missions": {r.name: row(r) for r in self.missions},
            "overall": row(self.overall),
        }


def split_summary(
    frames: Sequence[Frame], splits: Sequence[str], blocks: Sequence[str], config: SplitConfig
) -> SplitSummary:
    """Count frames and blocks per mission and split.

    Args:
        frames: the frames that were split.
        splits: the split of each frame (``assign_blocks``).
        blocks: the block id of each frame (:func:`block_ids`).
        config: the split's config (for its targets, block size and seed).
    """
    frame_count: dict[str, Counter] = defaultdict(Counter)
    block_sets: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    for frame, split, block in zip(frames, splits, blocks, strict=True):
        folder = MISSIONS[frame.mission]
        frame_count[folder][split] += 1
        block_sets[folder][split].add(block)
    order = [m for m in MISSIONS.values() if m in frame_count]
    rows = tuple(
        Shares(
            m,
            tuple(frame_count[m][s] for s in SPLITS),
            tuple(len(block_sets[m][s]) for s in SPLITS),
        )
        for m in order
    )
    overall = Shares(
        "all",
        tuple(sum(r.frames[i] for r in rows) for i in range(len(SPLITS))),
        tuple(sum(r.blocks[i] for r in rows) for i in range(len(SPLITS))),
    )
    return SplitSummary(tuple(config.fractions), config.block_size, config.seed, rows, overall)


def summarize_split(
    frames: Sequence[Frame], positions: np.ndarray, config: SplitConfig
) -> SplitSummary:
    """The shares the split of ``config`` realises on these frames (no warning)."""
    if config.val_missions or config.test_missions:
        splits = assign_blocks(frames, positions, config)
        return split_summary(
            frames, splits, block_ids(frames, positions, config.block_size), config
        )
    return split_summary(frames, *_deal(frames, positions, config), config)


def suggest_block_size(
    frames: Sequence[Frame],
    positions: np.ndarray,
    config: SplitConfig,
    tolerance: float = TOLERANCE,
) -> float | None:
    """The largest of :data:`CANDIDATE_BLOCK_SIZES` below ``config.block_size`` whose dealing
    keeps every mission within ``tolerance`` of the targets (measured by dealing at each);
    None when none does.
    """
    for size in CANDIDATE_BLOCK_SIZES:
        if size < config.block_size:
            candidate = dataclasses.replace(config, block_size=float(size))
            if not summarize_split(frames, positions, candidate).off_target(tolerance):
                return float(size)
    return None


def _balance_message(summary: SplitSummary, suggestion: float | None) -> str:
    off = [r for r in summary.off_target() if r.name != "all"] or [summary.overall]

    def pct(values: Sequence[float]) -> str:
        return "/".join(f"{100 * v:.0f}" for v in values)

    rows = ", ".join(f"{r.name} ({sum(r.blocks)} block(s): {pct(r.shares)} %)" for r in off)
    size = f"{summary.block_size:g}"
    if suggestion is not None:
        advice = (
            f"block_size={suggestion:g} (measured) brings every mission within "
            f"{100 * TOLERANCE:.0f} points, at the cost of more frames near split borders"
        )
    else:
        tried = [c for c in CANDIDATE_BLOCK_SIZES if c < summary.block_size]
        tried_text = f"no block size down to {min(tried):g} m balances them: " if tried else ""
        advice = (
            f"{tried_text}hold whole missions out (val_missions/test_missions) or use a split file"
        )
    return (
        f"{len(off)} of {len(summary.missions)} mission(s) have {'/'.join(SPLITS)} shares more "
        f"than {100 * TOLERANCE:.0f} points off the target {pct(summary.targets)} % with "
        f"{size} m blocks: {rows}; overall {pct(summary.overall.shares)} % of "
        f"{sum(summary.overall.frames)} frames. {advice}"
    )


def read_split_file(path: str | Path) -> list[str]:
    """Frame keys listed in a split file, one per line; ``#`` starts a comment.

    Read as UTF-8; a byte-order mark (as some Windows editors write) is skipped.

    A line is a frame key ``<mission folder>/<viewpoint>/<stem>`` or the path of any of the
    frame's files relative to the root (``003_urban_1/left_rgb/45deg_low_h/000123.jpg``).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"split file not found: {path}")
    keys = []
    for number, line in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), 1):
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

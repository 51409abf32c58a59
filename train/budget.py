"""Label budgets: train on a fraction of a dataset's labelled training images, drawn by whole
sequence, flight or block.

``data.budget=0.1`` keeps about 10 % of the training split's images. They are drawn as whole
units (``data.budget_by``): UAVid and AeroScapes sequences, ClaraVid spatial blocks (the
split's own unit) or passes (viewpoint folders), or image folders (any dataset that lists its
``images`` below a ``root``), never single images, so no kept image has its overlapping
neighbour left out of the budget, or the other way round. A split whose images all lie in one
unit (a flat folder) has no share to draw below 1.0, and says so. The draw is::

    units = sorted unit names; order = permutation(len(units), seed=data.budget_seed)
    keep the first k units of that order, k >= 1 the count whose images come closest to
    fraction × images (a tie keeps the larger)

Every budget of one seed is a prefix of the same order, so a smaller budget's images are a
subset of a larger one's (nested), and ``1.0`` keeps every image. Units hold different numbers
of images, so the realised share differs from the asked one (UAVid: sequences of 10 frames);
:class:`Budget` records both, the units kept, and the kept images' count and digest.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.targets import UAVidSegmentation
from claravid.train.config.schema import BUDGET_UNITS

__all__ = ["BUDGET_UNITS", "Budget", "BudgetError", "apply_budget", "draw_budget", "draw_units"]

#: The unit ``auto`` draws, per dataset kind (``data.dataset``); any other kind: ``folder``.
DEFAULT_UNIT = {"uavid": "sequence", "claravid": "block", "aeroscapes": "sequence"}
#: The units each dataset kind has (``folder``: an image's parent folder below the root; an
#: AeroScapes sequence is the first field of its names, ``000001`` of ``000001_001.jpg``).
UNITS_OF = {
    "uavid": ("sequence", "folder"),
    "claravid": ("block", "pass", "mission", "folder"),
    "aeroscapes": ("sequence", "folder"),
}


class BudgetError(ValueError):
    """A label budget that cannot be drawn (the message names the key and what to do)."""


@dataclass(frozen=True)
class Budget:
    """What a label budget kept of the training split.

    Attributes:
        fraction: the share asked for (``data.budget``).
        unit: the unit drawn whole (``sequence``, ``block``, ``pass``, ``mission``, ``folder``).
        seed: ``data.budget_seed``.
        units: the units kept, in draw order; None for 1.0, which draws nothing (every image
            is kept, and the units are not even named: a ClaraVid block needs the extrinsics).
        num_units: units in the whole split (None for 1.0).
        keys: the kept images' keys (relative paths without extension), sorted.
        num_images: images in the whole split.
        indices: the kept images' indices into the whole split, ascending.
    """

    fraction: float
    unit: str
    seed: int
    units: tuple[str, ...] | None
    num_units: int | None
    keys: tuple[str, ...]
    num_images: int
    indices: tuple[int, ...]

    @property
    def realised(self) -> float:
        """The share of the split's images kept."""
        return len(self.keys) / self.num_images

    @property
    def digest(self) -> str:
        """SHA-256 of the kept keys, one per line, sorted: equal digests, equal images."""
        return hashlib.sha256("".join(k + "\n" for k in self.keys).encode()).hexdigest()

    def record(self, keys: bool = False) -> dict[str, Any]:
        """Plain values for the checkpoint; with ``keys``, also every kept image's key (what
        ``out_dir/budget.json`` holds)."""
        record = {
            "fraction": self.fraction,
            "unit": self.unit,
            "seed": self.seed,
            "realised": self.realised,
            "num_units": self.num_units,
            "units": None if self.units is None else list(self.units),
            "num_images": self.num_images,
            "kept_images": len(self.keys),
            "digest": self.digest,
        }
        return {**record, "keys": list(self.keys)} if keys else record

    def line(self) -> str:
        """One line for the run's log."""
        if self.units is None:
            return f"label budget: every image ({self.num_images}), sha256 {self.digest[:12]}"
        return (
            f"label budget: data.budget={self.fraction:g} by {self.unit} (seed {self.seed}): "
            f"{len(self.units)} of {self.num_units} {self.unit} unit(s), {len(self.keys)} of "
            f"{self.num_images} images ({100 * self.realised:.1f} %), sha256 {self.digest[:12]}"
        )


def draw_units(labels: Sequence[str], fraction: float, seed: int) -> tuple[list[str], list[int]]:
    """The units kept and the indices of their items, for items labelled with their unit.

    Args:
        labels: each item's unit.
        fraction: in (0, 1].
        seed: the draw's seed (the same for every budget of one curve).

    Returns:
        ``(units in draw order, kept item indices ascending)``.
    """
    if not 0 < fraction <= 1:
        raise BudgetError(f"bad value for data.budget: {fraction!r} (a fraction in (0, 1])")
    names = sorted(set(labels))
    if not names:
        return [], []
    order = [names[i] for i in np.random.default_rng(seed).permutation(len(names))]
    sizes = {name: 0 for name in names}
    for label in labels:
        sizes[label] += 1
    cumulative = np.cumsum([sizes[name] for name in order])
    target = fraction * len(labels)
    # The first of the reversed minima: the larger k on a tie. Monotone in the target, so
    # budgets of one seed are nested prefixes; 1.0 reaches every unit exactly.
    distance = np.abs(cumulative - target)[::-1]
    k = len(order) - int(np.argmin(distance))
    kept = set(order[:k])
    return order[:k], [i for i, label in enumerate(labels) if label in kept]


def dataset_kind(dataset: Any) -> str:
    """``claravid``, ``uavid``, the name a dataset of another real layout gives itself
    (``dataset``: ``aeroscapes``, ``udd6`` ...), or ``folder``."""
    if isinstance(dataset, ClaraVidSegmentation):
        return "claravid"
    if isinstance(dataset, UAVidSegmentation):
        return "uavid"
    return str(getattr(dataset, "dataset", None) or "folder")


def unit_labels(dataset: Any, unit: str, named: bool = True) -> tuple[list[str], list[str]]:
    """``(keys, unit labels)`` of every image of a training split: ClaraVid's frames, or the
    ``images`` (paths below ``root``) of UAVid and the other real datasets; without ``named``,
    the unit is only checked (ClaraVid blocks, from the extrinsics, are not made).

    Raises:
        BudgetError: the dataset has no such unit, or neither frames nor images.
    """
    kind = dataset_kind(dataset)
    units = UNITS_OF.get(kind, ("folder",))
    if unit not in units:
        raise BudgetError(
            f"bad value for data.budget_by: {unit!r} ({kind} images are drawn by "
            f"{', '.join(units)}, or auto: {DEFAULT_UNIT.get(kind, 'folder')})"
        )
    if isinstance(dataset, ClaraVidSegmentation):
        keys = [f.key for f in dataset.frames]
        folders = [str(Path(k).parent) for k in keys]
        if unit == "block":
            return keys, dataset.block_ids() if named else []
        return keys, {"pass": folders, "mission": [k.split("/", 1)[0] for k in keys],
                      "folder": folders}[unit]  # fmt: skip
    images = getattr(dataset, "images", None)
    if not isinstance(images, list):
        raise BudgetError(_unsupported(dataset))
    paths = [Path(p) for p in images]
    keys = [p.relative_to(dataset.root).with_suffix("").as_posix() for p in paths]
    if unit == "folder":
        return keys, [str(Path(k).parent) for k in keys]
    if kind == "uavid":  # seqN/Images/NNNNNN.png
        return keys, [p.parent.parent.name for p in paths]
    return keys, [p.stem.split("_", 1)[0] for p in paths]  # AeroScapes: SSSSSS_FFF


def draw_budget(dataset: Any, fraction: float, unit: str = "auto", seed: int = 0) -> Budget:
    """The label budget of a training split (the dataset is not changed: see `apply_budget`).

    Raises:
        BudgetError: a fraction outside (0, 1], a unit the dataset does not have.
    """
    if not 0 < fraction <= 1:
        raise BudgetError(f"bad value for data.budget: {fraction!r} (a fraction in (0, 1])")
    if unit == "auto":
        unit = DEFAULT_UNIT.get(dataset_kind(dataset), "folder")
    if fraction == 1:  # nothing to draw: every image, the unit only checked
        keys, _ = unit_labels(dataset, unit, named=False)
        every = tuple(range(len(keys)))
        return Budget(float(fraction), unit, int(seed), None, None, tuple(sorted(keys)),
                      len(keys), every)  # fmt: skip
    keys, labels = unit_labels(dataset, unit)
    if len(set(labels)) == 1:
        raise BudgetError(
            f"data.budget={fraction:g} draws whole {unit}s, and the {len(keys)} training images "
            f"are all in one {unit} ({labels[0]}): no share of them can be drawn without "
            "splitting it; choose another data.budget_by, or train on every image "
            "(data.budget=1.0)"
        )
    units, indices = draw_units(labels, fraction, seed)
    return Budget(
        fraction=float(fraction),
        unit=unit,
        seed=int(seed),
        units=tuple(units),
        num_units=len(set(labels)),
        keys=tuple(sorted(keys[i] for i in indices)),
        num_images=len(keys),
        indices=tuple(indices),
    )


def _unsupported(dataset: Any) -> str:
    return f"label budgets draw from datasets of frames or images, not {type(dataset).__name__}"


def apply_budget(dataset: Any, budget: Budget) -> None:
    """Keep only the budget's images in ``dataset``, in place, in the split's order (ClaraVid's
    ``frames``; otherwise ``images`` and, where the dataset lists them beside, ``masks``)."""
    if isinstance(dataset, ClaraVidSegmentation):
        dataset.frames = [dataset.frames[i] for i in budget.indices]
        return
    lists = [name for name in ("images", "masks")
             if isinstance(getattr(dataset, name, None), list)]  # fmt: skip
    if "images" not in lists:
        raise BudgetError(_unsupported(dataset))
    for name in lists:
        values = getattr(dataset, name)
        if len(values) != budget.num_images:  # not the split this budget was drawn from
            raise BudgetError(f"the budget was drawn from {budget.num_images} images, not "
                              f"{len(values)}")  # fmt: skip
        setattr(dataset, name, [values[i] for i in budget.indices])

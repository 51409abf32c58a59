"""A model of ClaraVid's 19 fine classes scored on another palette's classes.

A palette's ClaraVid side (its ``mapping:``) sends each ClaraVid class to one palette class, or
to ignore. A model trained on the fine palette (``claravid``: one train id per ClaraVid class)
is scored on such a palette as SynDrone scores its fine model on coarse classes: per pixel, the
softmax probabilities of the fine classes are summed per palette class (the fine classes the
palette ignores drop out) and the prediction is the argmax of the sums, the lowest class on
ties. The summed probability of the predicted class is the pixel's confidence (calibration);
it is not renormalised, so the mass of the ignored fine classes is not handed to the others.

Only the static mapping applies: a ``dynamic:`` override (UAVid's Moving car) needs the dynamic
mask, which a model does not see. A palette class that no fine class reaches is never
predicted: :attr:`PaletteFold.reachable` says which are.

A saved label map of the fine model (one fine id per pixel) follows the same rule with its
one-hot scores: each fine id becomes its palette class; a fine id the palette ignores has no
vote at all, so the argmax falls to the tie rule: the lowest class that can be predicted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from claravid.data.palettes import Palette, PaletteError, load_palette
from claravid.io.labels import DYNAMIC_OFFSET
from claravid.io.layout import CLASSES, UNLABELED_ID

#: The palette whose train ids are ClaraVid's classes, one each.
FINE = "claravid"


def fine_names() -> tuple[str, ...]:
    """The fine palette's class names, in train-id order."""
    return load_palette(FINE).names


def is_fine(names: Sequence[str] | None) -> bool:
    """Whether a model's class names are the fine palette's (ClaraVid's 19, in order)."""
    return names is not None and tuple(names) == fine_names()


@dataclass(frozen=True)
class PaletteFold:
    """How the fine classes fold into a palette's classes.

    Attributes:
        target: the palette scored on.
        table: int64 [19]: the palette train id of each fine class, -1 where it is ignored.
    """

    target: Palette
    table: np.ndarray

    @property
    def num_source(self) -> int:
        """The fine classes: 19."""
        return len(self.table)

    @property
    def reachable(self) -> np.ndarray:
        """bool [K]: the palette classes some fine class folds into (the others are never
        predicted)."""
        out = np.zeros(self.target.num_classes, dtype=bool)
        out[self.table[self.table >= 0]] = True
        return out

    def matrix(self) -> np.ndarray:
        """float32 [K, 19]: 1 where fine class j folds into palette class i (sums the fine
        probabilities per palette class in one product)."""
        out = np.zeros((self.target.num_classes, self.num_source), dtype=np.float32)
        kept = np.flatnonzero(self.table >= 0)
        out[self.table[kept], kept] = 1.0
        return out

    def label_table(self) -> np.ndarray:
        """uint8 [256]: fine id -> palette id of a saved label map. A fine id the palette
        ignores goes to the lowest reachable class (the argmax of all-zero votes); ids above
        the fine classes stay out of range, so the reader's check still refuses them."""
        lut = np.full(256, UNLABELED_ID, dtype=np.uint8)
        lowest = int(np.flatnonzero(self.reachable)[0])
        lut[: self.num_source] = np.where(self.table >= 0, self.table, lowest)
        return lut

    def describe(self) -> dict[str, Any]:
        """The report's ``source["fold"]``: the model was scored through a palette it was not
        trained on, and how each fine class was counted."""
        names = fine_names()
        return {
            "model_palette": FINE,
            "palette": self.target.name,
            "rule": "summed fine softmax probabilities per palette class, argmax",
            "table": {
                name: (self.target.names[t] if t >= 0 else "ignore")
                for name, t in zip(names, self.table.tolist(), strict=True)
            },
            "unreachable": [
                n for n, r in zip(self.target.names, self.reachable, strict=True) if not r
            ],
        }


def fold_palette(model_names: Sequence[str], target: Palette) -> PaletteFold:
    """The fold of the fine classes into ``target`` through its ClaraVid side.

    Raises:
        PaletteError: ``model_names`` are not the fine palette's, or ``target`` maps every
            ClaraVid class to ignore (nothing could be predicted).
    """
    if not is_fine(model_names):
        raise PaletteError(
            f"a model is scored through another palette only when it predicts ClaraVid's "
            f"{len(fine_names())} classes (palette {FINE}); this one predicts "
            f"{len(model_names)}: {', '.join(model_names)}"
        )
    by_name = {c.name: c.id for c in CLASSES if c.id != UNLABELED_ID}
    table = np.asarray(
        [int(target.lut[by_name[name]]) for name in model_names], dtype=np.int64
    )  # the static mapping: lut[id]; lut[id + DYNAMIC_OFFSET] is the dynamic override
    table[table == target.ignore_index] = -1
    if (table < 0).all():
        raise PaletteError(
            f"palette {target.name} maps every ClaraVid class to ignore: a ClaraVid model "
            "cannot be scored on it"
        )
    table.setflags(write=False)
    return PaletteFold(target, table)


def reachable_from_palette(palette: Palette) -> np.ndarray:
    """bool [K]: the palette classes some ClaraVid class maps to (statically or through a
    ``dynamic:`` override): what a model trained on ClaraVid through this palette can
    predict."""
    codes = [c.id for c in CLASSES if c.id != UNLABELED_ID]
    hit = np.concatenate([palette.lut[codes], palette.lut[[c + DYNAMIC_OFFSET for c in codes]]])
    out = np.zeros(palette.num_classes, dtype=bool)
    out[hit[hit < palette.num_classes]] = True
    return out

"""The per-image sums of the measures beyond mIoU: boundaries, calibration, cross-view pairs.

Each measure is stored per image as sums, like the confusion matrix, so that a set's value (a
bin, a group, a resample of the bootstrap, a merge of parts) is a statistic of its images'
summed rows (:mod:`claravid.eval.analysis.quality`):

- ``boundary``: int64 [N, 2, K], each image's boundary intersections and unions per class;
- ``calibration``: float64 [N, 3, B], per confidence bin the pixel count, the sum of the
  confidences and the count of correct pixels;
- ``pairs`` (:class:`PairTable`): frame t's pair with the next frame s of its pass (a pair
  belongs to its frame t, so a pair is counted once whichever run or rank evaluates s).

A measure that was not computed has no array and a status that says why
(:data:`COMPUTED`, :data:`OFF`, :data:`UNAVAILABLE`, :data:`ABSENT`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

BOUNDARY, CALIBRATION, CONSISTENCY = "boundary_iou", "calibration", "consistency"
#: The measures beyond mIoU, in report order.
QUALITY = (BOUNDARY, CALIBRATION, CONSISTENCY)

#: A measure's status: computed; switched off by the user; not computable for this source or
#: data (no scores, no depth); absent from a report written before the measure existed.
COMPUTED, OFF, UNAVAILABLE, ABSENT = "computed", "off", "unavailable", "absent"

#: A pair's status: counted; skipped as a turn (too few kept pixels); the last frame of its
#: pass; unavailable (a file or a prediction missing); frames with identical poses (flagged:
#: their consistency would be 1 by construction, so they are left out of the sums).
PAIR_OK, PAIR_TURN, PAIR_LAST, PAIR_UNAVAILABLE, PAIR_IDENTICAL = (
    "ok",
    "turn",
    "last",
    "unavailable",
    "identical_poses",
)
PAIR_STATUSES = (PAIR_OK, PAIR_TURN, PAIR_LAST, PAIR_UNAVAILABLE, PAIR_IDENTICAL)

#: The fixed columns of a pair's sums; K intersections and K unions of the predictions, then of
#: the ground truth, follow.
PAIR_FIXED = ("kept", "agree", "agree_gt")


def pair_columns(num_classes: int) -> int:
    """The width of a pair's row of sums: the fixed columns and four per-class blocks."""
    return len(PAIR_FIXED) + 4 * num_classes


@dataclass
class PairTable:
    """Frame t's pair with the next frame s of its pass, one row per image of the table.

    Attributes:
        next: the key of frame s ("" when t is the last frame of its pass).
        status: one of :data:`PAIR_STATUSES`.
        reason: why a pair is unavailable ("" otherwise).
        sums: int64 [N, 3 + 4K]: kept pixels, kept pixels whose predictions agree, kept pixels
            whose ground truths agree, then per class the intersection and union of the
            predictions of t and s (carried back to t) over the kept pixels, then the same of
            the ground truths. Zero unless the status is :data:`PAIR_OK`.
    """

    next: list[str]
    status: list[str]
    reason: list[str]
    sums: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.next)
        if not (len(self.status) == len(self.reason) == n == len(self.sums)):
            raise ValueError(
                f"pair table of {n} frames with {len(self.status)} statuses, {len(self.reason)} "
                f"reasons and {len(self.sums)} rows of sums"
            )
        unknown = sorted(set(self.status) - set(PAIR_STATUSES))
        if unknown:
            raise ValueError(f"unknown pair status {unknown}; expected {', '.join(PAIR_STATUSES)}")

    def take(self, order: Sequence[int] | np.ndarray) -> PairTable:
        """The rows in ``order``."""
        order = list(order)
        return PairTable([self.next[i] for i in order], [self.status[i] for i in order],
                         [self.reason[i] for i in order], self.sums[order])  # fmt: skip

    def counts(self, members: Sequence[int] | None = None) -> dict[str, int]:
        """How many pairs of ``members`` (default all) have each status."""
        chosen = range(len(self.status)) if members is None else members
        out = dict.fromkeys(PAIR_STATUSES, 0)
        for i in chosen:
            out[self.status[i]] += 1
        return out


@dataclass
class QualityTable:
    """The measures beyond mIoU of every image of an
    :class:`~claravid.eval.analysis.table.EvalResult`, in its row order.

    Attributes:
        status: measure -> :data:`COMPUTED`, :data:`OFF`, :data:`UNAVAILABLE` or :data:`ABSENT`.
        reasons: measure -> why it is not computed (or, computed, a note such as the pairs
            left out); absent when there is nothing to say.
        boundary: int64 [N, 2, K] (intersections, unions) or None.
        calibration: float64 [N, 3, B] (count, confidence sum, correct) or None.
        pairs: frame t's pair sums (:class:`PairTable`) or None.
        settings: measure -> how it was computed (``{"dilation_ratio": 0.02}``...).
    """

    status: dict[str, str]
    reasons: dict[str, str] = field(default_factory=dict)
    boundary: np.ndarray | None = None
    calibration: np.ndarray | None = None
    pairs: PairTable | None = None
    settings: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        arrays = {BOUNDARY: self.boundary, CALIBRATION: self.calibration,
                  CONSISTENCY: self.pairs}  # fmt: skip
        for name in QUALITY:
            self.status.setdefault(name, ABSENT)
            if (self.status[name] == COMPUTED) != (arrays[name] is not None):
                raise ValueError(
                    f"{name} is {self.status[name]} but its sums are "
                    f"{'missing' if arrays[name] is None else 'given'}"
                )

    @classmethod
    def absent(cls, reason: str) -> QualityTable:
        """No measure beyond mIoU (a report written before them, or a table built without)."""
        return cls({m: ABSENT for m in QUALITY}, dict.fromkeys(QUALITY, reason))

    def computed(self, name: str) -> bool:
        """Whether ``name`` has sums."""
        return self.status.get(name) == COMPUTED

    def computed_sums(self, name: str) -> np.ndarray:
        """The sums of :data:`BOUNDARY` or :data:`CALIBRATION` (ValueError when not computed)."""
        if name not in (BOUNDARY, CALIBRATION):
            raise ValueError(f"{name} has no array of sums; expected {BOUNDARY} or {CALIBRATION}")
        sums = self.boundary if name == BOUNDARY else self.calibration
        if sums is None:
            raise ValueError(f"{name} is {self.status.get(name)}: the table holds no sums of it")
        return sums

    def computed_pairs(self) -> PairTable:
        """The pair sums of :data:`CONSISTENCY` (ValueError when not computed)."""
        if self.pairs is None:
            raise ValueError(
                f"{CONSISTENCY} is {self.status.get(CONSISTENCY)}: the table holds no pair sums"
            )
        return self.pairs

    def take(self, order: Sequence[int] | np.ndarray) -> QualityTable:
        """The rows in ``order`` (the status and settings unchanged)."""
        order = list(order)
        return QualityTable(
            dict(self.status),
            dict(self.reasons),
            None if self.boundary is None else self.boundary[order],
            None if self.calibration is None else self.calibration[order],
            None if self.pairs is None else self.pairs.take(order),
            {k: dict(v) for k, v in self.settings.items()},
        )


def concat_quality(
    tables: Sequence[QualityTable], names: Sequence[str], order: np.ndarray
) -> QualityTable:
    """Join the measures of merged parts (rows concatenated, then put in ``order``).

    A measure is kept when every part computed it with the same settings; otherwise it is
    marked as not computed, and the reason names the parts that lack it.
    """
    status: dict[str, str] = {}
    reasons: dict[str, str] = {}
    arrays: dict[str, Any] = {}
    settings: dict[str, dict[str, Any]] = {}
    for name in QUALITY:
        lacking = [f"{n} ({t.status[name]})" for t, n in zip(tables, names, strict=True)
                   if not t.computed(name)]  # fmt: skip
        computing = [t for t in tables if t.computed(name)]
        first = computing[0].settings.get(name, {}) if computing else {}
        lacking += [f"{n} (other settings: {t.settings.get(name)} vs {first})"
                    for t, n in zip(tables, names, strict=True)
                    if t.computed(name) and t.settings.get(name, {}) != first]  # fmt: skip
        if lacking:
            every = len(lacking) == len(tables)
            status[name] = tables[0].status[name] if every else UNAVAILABLE
            reasons[name] = (tables[0].reasons.get(name, "") if every else
                             f"not in every part: {', '.join(lacking)} lack it")  # fmt: skip
            if not reasons[name]:
                del reasons[name]
            continue
        status[name] = COMPUTED
        settings[name] = dict(first)
        if name in (BOUNDARY, CALIBRATION):
            arrays[name] = np.concatenate([t.computed_sums(name) for t in tables])[order]
        else:
            parts = [t.computed_pairs() for t in tables]
            joined = PairTable(
                [x for p in parts for x in p.next],
                [x for p in parts for x in p.status],
                [x for p in parts for x in p.reason],
                np.concatenate([p.sums for p in parts]),
            )
            arrays[name] = joined.take(order)
    return QualityTable(status, reasons, arrays.get(BOUNDARY), arrays.get(CALIBRATION),
                        arrays.get(CONSISTENCY), settings)  # fmt: skip

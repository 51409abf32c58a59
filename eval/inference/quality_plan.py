"""Which measures beyond mIoU an evaluation takes, and why the others are left out.

Boundary IoU needs a prediction and labels: every evaluation has it unless switched off.
Calibration needs scores: a checkpoint or an ONNX file has them, saved label maps do not.
Cross-view consistency needs depth, poses and the passes a frame belongs to: ClaraVid has them
(a partial download without depth or extrinsics is reported as unavailable, with the reason),
UAVid and folders of images do not. A measure asked for explicitly (``True``) that the source
or data cannot give is a user's mistake, refused before any work; one left at its default
(``None``) is quietly marked unavailable, with the reason in the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from claravid.eval.analysis.quality_table import (
    BOUNDARY,
    CALIBRATION,
    COMPUTED,
    CONSISTENCY,
    OFF,
    QUALITY,
    UNAVAILABLE,
)
from claravid.eval.inference.image_sums import CALIBRATION_BINS, DILATION_RATIO, ImageMeasures
from claravid.eval.measures.cross_view import MIN_KEPT, TOLERANCE
from claravid.infra.cli import UsageError

#: How the pairs' consistency is computed (what a report records).
CONSISTENCY_SETTINGS = {"tau": TOLERANCE, "min_kept": MIN_KEPT}
_FLAGS = {BOUNDARY: "--boundary", CALIBRATION: "--calibration", CONSISTENCY: "--consistency"}


@dataclass(frozen=True)
class QualityPlan:
    """The measures beyond mIoU of one evaluation.

    Attributes:
        status: measure -> :data:`COMPUTED` (to be computed), :data:`OFF` or
            :data:`UNAVAILABLE`.
        reasons: measure -> why it is not computed.
        settings: measure -> how it is computed (recorded in the report).
    """

    status: dict[str, str]
    reasons: dict[str, str] = field(default_factory=dict)
    settings: dict[str, dict[str, Any]] = field(default_factory=dict)

    def on(self, name: str) -> bool:
        """Whether ``name`` is computed."""
        return self.status[name] == COMPUTED

    def image_measures(self) -> ImageMeasures:
        """What each image measures beside its confusion."""
        return ImageMeasures(boundary=self.on(BOUNDARY), calibration=self.on(CALIBRATION),
                             dilation_ratio=DILATION_RATIO, bins=CALIBRATION_BINS)  # fmt: skip


def plan_quality(
    asked: dict[str, bool | None], *, has_scores: bool, pairs_reason: str | None
) -> QualityPlan:
    """Decide each measure from what was asked and what the source and data allow.

    Args:
        asked: measure -> True (required), False (off) or None (on where possible).
        has_scores: the source gives scores (a model), not label maps.
        pairs_reason: why the data has no cross-view pairs (None: it has them).

    Raises:
        UsageError: a measure asked for explicitly that the source or data cannot give.
    """
    cannot: dict[str, str | None] = {
        BOUNDARY: None,
        CALIBRATION: None if has_scores else (
            "label maps have no scores: evaluate the checkpoint or ONNX file"),
        CONSISTENCY: pairs_reason,
    }  # fmt: skip
    status: dict[str, str] = {}
    reasons: dict[str, str] = {}
    for name in QUALITY:
        wanted = asked.get(name)
        if wanted is False:
            status[name] = OFF
        elif (why := cannot[name]) is not None:
            if wanted:
                raise UsageError(f"{_FLAGS[name]} cannot be computed: {why}; drop "
                                 f"{_FLAGS[name]}")  # fmt: skip
            status[name], reasons[name] = UNAVAILABLE, why
        else:
            status[name] = COMPUTED
    settings: dict[str, dict[str, Any]] = {BOUNDARY: {"dilation_ratio": DILATION_RATIO},
                CALIBRATION: {"bins": CALIBRATION_BINS, "norm": "l1"},
                CONSISTENCY: dict(CONSISTENCY_SETTINGS)}  # fmt: skip
    return QualityPlan(status, reasons, {n: settings[n] for n in QUALITY if status[n] == COMPUTED})

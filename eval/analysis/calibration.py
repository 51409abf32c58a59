"""Calibration errors and the reliability diagram from summed per-bin calibration sums.

Each image stores, per confidence bin, its pixel count ``n_b``, the sum of its confidences and
its correct pixels (:mod:`claravid.eval.measures.calibration_sums`); a group's sums are the sums of
its images'. Then, as ``torchmetrics``' ``MulticlassCalibrationError``:

- ECE = Σ_b (n_b / N) · |acc_b − conf_b| = Σ_b |correct_b − conf_sum_b| / N (``norm="l1"``);
- MCE = the largest |acc_b − conf_b| over non-empty bins (``norm="max"``);
- the reliability diagram plots acc_b = correct_b / n_b against conf_b = conf_sum_b / n_b.

No pixel at all gives NaN, never 0.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def reliability(
    count: ArrayLike, conf_sum: ArrayLike, correct: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bin: mean confidence, accuracy (NaN where empty) and share of the pixels (float64)."""
    n = np.asarray(count, dtype=np.float64)
    s, k = np.asarray(conf_sum, dtype=np.float64), np.asarray(correct, dtype=np.float64)
    if not n.shape == s.shape == k.shape or n.ndim != 1:
        raise ValueError(
            f"count, conf_sum and correct must be 1-D arrays of one length, got {n.shape}, "
            f"{s.shape}, {k.shape}"
        )
    _check_sums(n, s, k)
    total = n.sum()
    with np.errstate(invalid="ignore", divide="ignore"):
        confidence = np.where(n > 0, s / np.where(n > 0, n, 1), np.nan)
        accuracy = np.where(n > 0, k / np.where(n > 0, n, 1), np.nan)
        share = n / total if total > 0 else np.full_like(n, np.nan)
    return confidence, accuracy, share


def _check_sums(n: np.ndarray, s: np.ndarray, k: np.ndarray) -> None:
    """Sums that no image can give (a negative count, more correct pixels or a larger
    confidence sum than pixels, NaN) are refused, not turned into a NaN error."""
    problems = [
        (name, bad)
        for name, bad in (
            ("not finite", ~(np.isfinite(n) & np.isfinite(s) & np.isfinite(k))),
            ("negative", (n < 0) | (s < 0) | (k < 0)),
            ("more correct pixels than pixels", k > n),
            ("a confidence sum above the pixel count", s > n * (1 + 1e-9)),
        )
        if bad.any()
    ]
    if problems:
        name, bad = problems[0]
        raise ValueError(
            f"calibration sums {name} in bin(s) {np.flatnonzero(bad)[:5].tolist()}: pass the "
            "(count, conf_sum, correct) that calibration_bins gives, summed over images"
        )


def calibration_errors(
    count: ArrayLike, conf_sum: ArrayLike, correct: ArrayLike
) -> tuple[float, float]:
    """(ECE, MCE) of summed per-bin sums; (NaN, NaN) when no pixel counts."""
    confidence, accuracy, _ = reliability(count, conf_sum, correct)
    n = np.asarray(count, dtype=np.float64)
    total = n.sum()
    if total <= 0:
        return float("nan"), float("nan")
    gaps = np.abs(np.asarray(correct, np.float64) - np.asarray(conf_sum, np.float64))
    ece = float(gaps.sum() / total)
    mce = float(np.nanmax(np.abs(accuracy - confidence)))
    return ece, mce

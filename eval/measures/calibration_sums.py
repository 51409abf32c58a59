"""Calibration sums of one image: per confidence bin, pixels, summed confidence, correct pixels.

As ``torchmetrics``' ``MulticlassCalibrationError`` (``norm="l1"`` for ECE, ``"max"`` for MCE,
15 equal-width bins) sees a pixel: its confidence is its largest class probability, its
prediction the class of that probability, and it is correct when that class is the ground
truth's. Pixels whose ground truth is the ignore index (255) do not count. Bins are
torchmetrics' too: the edges are ``torch.linspace(0, 1, n_bins + 1)`` in float32 and a
confidence falls in the bin whose left edge it reaches (``[e_i, e_{i+1})``); a confidence of
exactly 1 falls in the last bin, which is therefore closed (torchmetrics keeps such pixels in a
bin of their own past the last one, which only matters for saturated probabilities).

An image stores the three sums per bin, so a group's ECE = Σ_b |correct_b − conf_sum_b| / N and
its reliability diagram (accuracy against confidence per bin) come from summed images, as mIoU
comes from a summed confusion (:mod:`claravid.eval.analysis.calibration`).

Confidence sums are exact: a confidence of at least 2^-7 is a multiple of 2^-30, so the sums of
``x · 2^30`` are integers, and smaller ones add their significands per binary exponent; a bin's
sum is the float64 nearest to the exact sum of its float32 confidences (``math.fsum`` of the
parts), whatever the order of the pixels. The integers come from one pass in C when the
optional module ``_calibration`` was built at install, and from numpy otherwise: the same
numbers to the bit.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import torch

from claravid.data.ignore import IGNORE_INDEX
from claravid.eval.measures.label_ids import as_numpy, check_ids, label_image

try:  # the optional C pass (built at install when a compiler is there)
    from claravid.eval.measures import _calibration as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None  # type: ignore[assignment]  # mypy types a module name as never None
if not hasattr(_native, "exact_sums"):  # pragma: no cover - a build older than this module
    _native = None  # type: ignore[assignment]
#: Whether the C pass may take eight pixels at a time where the CPU has AVX2 (tests turn it off
#: to check the one-pixel pass).
_vector = True

#: torchmetrics' default and the report's.
N_BINS = 15


def bin_edges(n_bins: int = N_BINS) -> np.ndarray:
    """The float32 bin edges, ``torch.linspace(0, 1, n_bins + 1)`` (torchmetrics' own)."""
    if isinstance(n_bins, bool) or not isinstance(n_bins, (int, np.integer)) or n_bins < 1:
        raise ValueError(f"n_bins must be a positive integer, got {n_bins!r}")
    return torch.linspace(0, 1, int(n_bins) + 1, dtype=torch.float32).numpy()


def calibration_bins(
    probs: Any, gt: Any, n_bins: int = N_BINS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-bin pixel count, sum of confidences and count of correct pixels of one image.

    Args:
        probs: class probabilities [K, H, W] (the softmax of the logits, after window
            averaging), numpy or torch on any device; reduced where they are, then counted on
            the CPU in float32.
        gt: ground-truth class ids [H, W]; 255 is ignored.
        n_bins: equal-width confidence bins over [0, 1].

    Returns:
        ``(count, conf_sum, correct)``: int64, float64 and int64 arrays of ``n_bins``.

    Raises:
        ValueError: shapes that do not fit, ground-truth ids outside ``[0, K)`` (other than 255),
            or confidences outside [0, 1] (logits passed instead of probabilities).
    """
    confidence, prediction = confidence_and_prediction(probs)
    return calibration_sums(confidence, prediction, gt, n_bins, num_classes=int(probs.shape[0]))


def confidence_and_prediction(probs: Any) -> tuple[np.ndarray, np.ndarray]:
    """The largest probability (float32 H×W) and its class (uint8 H×W) of [K, H, W] scores.

    One reduction over the classes, on the tensor's device; ties go to the lowest class, as
    ``torch.max`` (and torchmetrics) has it.
    """
    scores = probs if isinstance(probs, torch.Tensor) else torch.from_numpy(np.asarray(probs))
    if scores.ndim != 3 or scores.shape[0] < 1:
        raise ValueError(f"probs must be [K, H, W] class probabilities, got {tuple(scores.shape)}")
    if not scores.is_floating_point():
        raise ValueError(f"probs must be floating point probabilities, got {scores.dtype}")
    if scores.shape[0] > IGNORE_INDEX:
        raise ValueError(f"at most {IGNORE_INDEX} classes, got {scores.shape[0]}")
    with torch.no_grad():
        confidence, prediction = scores.max(dim=0)
    return (
        confidence.to(torch.float32).cpu().numpy(),
        prediction.to(torch.uint8).cpu().numpy(),
    )


def calibration_sums(
    confidence: Any,
    prediction: Any,
    gt: Any,
    n_bins: int = N_BINS,
    num_classes: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`calibration_bins` from each pixel's confidence and predicted class.

    For a caller that already has them (the evaluator takes the prediction from the same
    reduction as the confidence). ``num_classes`` checks the ground truth's ids when given.
    """
    edges = bin_edges(n_bins)
    conf = as_numpy(confidence)
    if conf.ndim != 2:
        raise ValueError(f"confidence must be H×W, got shape {conf.shape}")
    conf = np.ascontiguousarray(conf, dtype=np.float32)
    pred = label_image(prediction, "prediction")
    truth = label_image(gt, "ground truth")
    if not conf.shape == pred.shape == truth.shape:
        raise ValueError(
            f"confidence {conf.shape}, prediction {pred.shape} and ground truth {truth.shape} "
            "differ in shape"
        )
    if num_classes is not None:
        check_ids(truth, None, num_classes, "")
    bins = len(edges) - 1
    if _native is not None and bins < _AMBIGUOUS:
        count, correct, fixed = (np.zeros(bins, np.int64) for _ in range(3))
        small = np.zeros((bins, _EXPONENTS), np.int64)
        try:
            _native.exact_sums(conf, pred, truth, edges, _bin_table(bins), count, correct, fixed,
                               small, _vector)  # fmt: skip
        except ValueError as error:
            raise ValueError(f"{error}: pass probabilities (the softmax of the logits)") from None
    else:
        count, correct, fixed, small = _numpy_parts(conf, pred, truth, edges)
    return count, _confidence_sums(fixed, small), correct


def _confidence_sums(fixed: np.ndarray, small: np.ndarray) -> np.ndarray:
    """float64 [bins]: each bin's ``fixed · 2^-30 + Σ_e small[e] · 2^(e − 150)``, rounded once."""
    out = np.zeros(len(fixed))
    for k, (whole, parts) in enumerate(zip(fixed.tolist(), small, strict=True)):
        units, rest = divmod(whole, 1 << _FIXED_BITS)  # two exact float64 terms
        terms = [float(units), math.ldexp(rest, -_FIXED_BITS)]
        terms += [math.ldexp(int(parts[e]), int(e) - 150) for e in np.flatnonzero(parts)]
        out[k] = math.fsum(terms)
    return out


@functools.lru_cache(maxsize=8)
def _bin_table(n_bins: int) -> np.ndarray:
    """The C pass's bin of every float32 bit pattern's top 16 bits (uint8 [65536]).

    A pattern whose whole range ``[key << 16, key << 16 | 0xFFFF]`` lies in one bin (and in
    [0, 1]) gets that bin; one whose range holds an edge, 1.0 or -0.0 gets ``_AMBIGUOUS`` (the C
    pass compares with the edges); one that can only be outside [0, 1] gets ``_OUTSIDE``.
    """
    edges = bin_edges(n_bins)
    keys = np.arange(1 << 16, dtype=np.uint32) << 16
    low, high = keys.view(np.float32), (keys | 0xFFFF).view(np.float32)
    with np.errstate(invalid="ignore"):
        inside = (low >= 0) & (high <= 1)  # NaN patterns compare False
        maybe = (low >= 0) & (low <= 1)  # e.g. the pattern of 1.0, or of -0.0 (checked below)
    bin_low = np.searchsorted(edges[1:-1], low, side="right")
    bin_high = np.searchsorted(edges[1:-1], high, side="right")
    table = np.where(maybe, _AMBIGUOUS, _OUTSIDE).astype(np.uint8)
    table[inside & (bin_low == bin_high)] = bin_low[inside & (bin_low == bin_high)]
    table[0x8000] = _AMBIGUOUS  # -0.0 >= 0 holds: bin 0 (the rest of its range is negative)
    table.setflags(write=False)
    return table


_AMBIGUOUS, _OUTSIDE = 254, 255  # as in _calibration.c
_FIXED_BITS = 30  # x · 2^30 is whole for x >= 2^-7 (as FIXED_SCALE in _calibration.c)
_SMALL_BITS = 0x3C000000  # the float32 pattern of 2^-7 (as SMALL_BITS)
_EXPONENTS = 256  # small confidences' sums by binary exponent (as EXPONENTS)


def _numpy_parts(
    conf: np.ndarray, pred: np.ndarray, truth: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Count, correct, fixed-point and small-confidence sums with numpy (the C module's
    reference and fallback): the same integers."""
    bins = len(edges) - 1
    valid = truth != IGNORE_INDEX
    c = conf[valid]
    outside = ~((c >= 0) & (c <= 1))  # NaN too
    if outside.any():
        i = int(np.flatnonzero(valid.ravel())[np.argmax(outside)])
        raise ValueError(
            f"confidence {float(conf.ravel()[i])!r} at pixel {i} is not in [0, 1]: pass "
            "probabilities (the softmax of the logits)"
        )
    k = np.searchsorted(edges[1:-1], c, side="right")  # [e_i, e_i+1); 1.0 in the last bin
    count = np.bincount(k, minlength=bins).astype(np.int64)
    correct = np.bincount(k[pred[valid] == truth[valid]], minlength=bins).astype(np.int64)
    bits = c.view(np.uint32)
    small = bits < _SMALL_BITS  # -0.0 (0x80000000) is not: it adds 0 as a whole number
    whole = (c[~small].astype(np.float64) * (1 << _FIXED_BITS)).astype(np.int64)
    # Integer sums through float64 bincounts, exact in 15-bit halves (< 2^53 each).
    kw = k[~small]
    fixed = np.rint(np.bincount(kw, whole >> 15, bins)).astype(np.int64) << 15
    fixed += np.rint(np.bincount(kw, whole & 0x7FFF, bins)).astype(np.int64)
    exponent = (bits[small] >> 23).astype(np.int64)
    significand = (bits[small] & 0x7FFFFF) | np.where(exponent > 0, 0x800000, 0)
    index = k[small] * _EXPONENTS + np.maximum(exponent, 1)
    sums = np.bincount(index, significand.astype(np.float64), bins * _EXPONENTS)
    return count, correct, fixed, np.rint(sums).astype(np.int64).reshape(bins, _EXPONENTS)

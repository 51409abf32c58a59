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
parts), whatever the order of the pixels. Confidences held by a torch tensor are counted where
it lives (``torch.bucketize`` and integer ``scatter_add_``: a 12-Mpixel map never leaves the
GPU, only the per-bin integers do); numpy arrays (ONNX Runtime's output, saved maps) are counted
by numpy. Both make the same integers, so the same float64 sums to the bit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from claravid.data.ignore import IGNORE_INDEX
from claravid.eval.measures.label_ids import as_numpy, check_ids, label_image

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
            averaging), numpy or torch on any device; reduced and counted where they are, in
            float32.
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


def confidence_and_prediction(probs: Any) -> tuple[Any, Any]:
    """The largest probability (float32 H×W) and its class (uint8 H×W) of [K, H, W] scores.

    One reduction over the classes, on the tensor's device; ties go to the lowest class, as
    ``torch.max`` (and torchmetrics) has it. Tensors on the scores' device for a tensor, numpy
    arrays for numpy scores.
    """
    tensor = isinstance(probs, torch.Tensor)
    scores = probs if tensor else torch.from_numpy(np.asarray(probs))
    if scores.ndim != 3 or scores.shape[0] < 1:
        raise ValueError(f"probs must be [K, H, W] class probabilities, got {tuple(scores.shape)}")
    if not scores.is_floating_point():
        raise ValueError(f"probs must be floating point probabilities, got {scores.dtype}")
    if scores.shape[0] > IGNORE_INDEX:
        raise ValueError(f"at most {IGNORE_INDEX} classes, got {scores.shape[0]}")
    with torch.no_grad():
        confidence, prediction = scores.max(dim=0)
    confidence, prediction = confidence.to(torch.float32), prediction.to(torch.uint8)
    return (confidence, prediction) if tensor else (confidence.numpy(), prediction.numpy())


def calibration_sums(
    confidence: Any,
    prediction: Any,
    gt: Any,
    n_bins: int = N_BINS,
    num_classes: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`calibration_bins` from each pixel's confidence and predicted class.

    For a caller that already has them (the evaluator takes the prediction from the same
    reduction as the confidence). ``num_classes`` checks the ground truth's ids when given. A
    torch ``confidence`` is counted on its device (the labels are moved there when they are not),
    numpy by numpy; the numbers are the same.
    """
    edges = bin_edges(n_bins)
    if isinstance(confidence, torch.Tensor):
        count, correct, fixed, small = _torch_parts(confidence, prediction, gt, edges, num_classes)
        return count, _confidence_sums(fixed, small), correct
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
    count, correct, fixed, small = _numpy_parts(conf, pred, truth, edges)
    return count, _confidence_sums(fixed, small), correct


def _confidence_sums(fixed: np.ndarray, small: np.ndarray) -> np.ndarray:
    """float64 [bins]: each bin's ``fixed · 2^-30 + Σ_e small[e] · 2^(e − 150)``, rounded once."""
    out = np.zeros(len(fixed))
    for k, (whole, parts) in enumerate(zip(fixed.tolist(), small, strict=True)):
        units, rest = divmod(whole, 1 << FIXED_BITS)  # two exact float64 terms
        terms = [float(units), math.ldexp(rest, -FIXED_BITS)]
        terms += [math.ldexp(int(parts[e]), int(e) - 150) for e in np.flatnonzero(parts)]
        out[k] = math.fsum(terms)
    return out


FIXED_BITS = 30  # x · 2^30 is whole for x >= 2^-7
SMALL_BITS = 0x3C000000  # the float32 pattern of 2^-7: below it, x · 2^30 is not whole
EXPONENTS = 256  # small confidences' sums by binary exponent


def _numpy_parts(
    conf: np.ndarray, pred: np.ndarray, truth: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Count, correct, fixed-point and small-confidence sums with numpy (the same integers as
    :func:`_torch_parts`)."""
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
    small = bits < SMALL_BITS  # -0.0 (0x80000000) is not: it adds 0 as a whole number
    whole = (c[~small].astype(np.float64) * (1 << FIXED_BITS)).astype(np.int64)
    # Integer sums through float64 bincounts, exact in 15-bit halves (< 2^53 each).
    kw = k[~small]
    fixed = np.rint(np.bincount(kw, whole >> 15, bins)).astype(np.int64) << 15
    fixed += np.rint(np.bincount(kw, whole & 0x7FFF, bins)).astype(np.int64)
    exponent = (bits[small] >> 23).astype(np.int64)
    significand = (bits[small] & 0x7FFFFF) | np.where(exponent > 0, 0x800000, 0)
    index = k[small] * EXPONENTS + np.maximum(exponent, 1)
    sums = np.bincount(index, significand.astype(np.float64), bins * EXPONENTS)
    return count, correct, fixed, np.rint(sums).astype(np.int64).reshape(bins, EXPONENTS)


def _torch_parts(
    confidence: torch.Tensor, prediction: Any, gt: Any, edges: np.ndarray, num_classes: int | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_numpy_parts` on the confidence's device: the same integers.

    Ignored pixels go to a spare bin past the last (dropped at the end), so every pass works on
    the whole image, with no copy of its valid pixels; only the per-bin integers leave the
    device, in one transfer. Integer sums do not depend on the order the scatter adds them in.
    """
    device = confidence.device
    conf = confidence.detach().to(torch.float32).contiguous()
    pred, truth = (
        _device_labels(prediction, "prediction", device),
        _device_labels(gt, "ground truth", device),
    )
    if conf.ndim != 2 or not conf.shape == pred.shape == truth.shape:
        raise ValueError(
            f"confidence {tuple(conf.shape)}, prediction {tuple(pred.shape)} and ground truth "
            f"{tuple(truth.shape)} differ in shape (each must be H×W)"
        )
    bins = len(edges) - 1
    valid = truth != IGNORE_INDEX
    outside = valid & ~((conf >= 0) & (conf <= 1))  # NaN too
    bad = outside.any()
    if num_classes is not None:
        bad |= (valid & (truth >= num_classes)).any()
    if bad:  # one wait for the device, then the numpy path's error
        _raise_bad(conf, truth, outside, num_classes)
    inner = torch.from_numpy(np.ascontiguousarray(edges[1:-1])).to(device)
    k = torch.bucketize(conf, inner, right=True)  # [e_i, e_i+1); 1.0 in the last bin
    slot = torch.where(valid, k, bins).ravel()
    count = torch.bincount(slot, minlength=bins + 1)[:bins]
    correct = torch.bincount(torch.where(valid & (pred == truth), k, bins).ravel(),
                             minlength=bins + 1)[:bins]  # fmt: skip
    bits = conf.view(torch.int32)  # -0.0 is negative here: not small, it adds 0 as a whole
    small = valid & (bits >= 0) & (bits < SMALL_BITS)
    # x · 2^30 in float32 is exact (a power of two, x <= 1) and whole for x >= 2^-7.
    whole = (torch.where(valid & ~small, conf, 0.0) * float(1 << FIXED_BITS)).to(torch.int64)
    fixed = torch.zeros(bins + 1, dtype=torch.int64, device=device)
    fixed.scatter_add_(0, slot, whole.ravel())
    exponent = bits >> 23
    significand = (bits & 0x7FFFFF) | torch.where(exponent > 0, 0x800000, 0)
    index = torch.where(small, k * EXPONENTS + exponent.clamp(min=1), bins * EXPONENTS).ravel()
    sums = torch.zeros(bins * EXPONENTS + 1, dtype=torch.int64, device=device)
    sums.scatter_add_(0, index, torch.where(small, significand, 0).ravel().to(torch.int64))
    parts = torch.cat([count, correct, fixed[:bins], sums[:-1]]).cpu().numpy()
    counts, corrects, fixed_sums, rest = np.split(parts, [bins, 2 * bins, 3 * bins])
    return counts, corrects, fixed_sums, rest.reshape(bins, EXPONENTS)


def _device_labels(labels: Any, name: str, device: torch.device) -> torch.Tensor:
    """``labels`` as a uint8 H×W tensor on ``device`` (numpy's checks for what is not uint8)."""
    if isinstance(labels, torch.Tensor) and labels.dtype == torch.uint8:
        return labels.to(device)
    return torch.from_numpy(label_image(labels, name)).to(device)


def _raise_bad(
    conf: torch.Tensor, truth: torch.Tensor, outside: torch.Tensor, num_classes: int | None
) -> None:
    """The numpy path's error for an unknown ground-truth id or a confidence outside [0, 1]."""
    if num_classes is not None:
        check_ids(truth.cpu().numpy(), None, num_classes, "")
    i = int(outside.ravel().to(torch.uint8).argmax())  # the first such pixel
    raise ValueError(
        f"confidence {float(conf.ravel()[i])!r} at pixel {i} is not in [0, 1]: pass "
        "probabilities (the softmax of the logits)"
    )

"""Label images as the per-image measures take them: 2-D uint8 arrays, ids checked once.

Boundary IoU, calibration and cross-view consistency accept numpy arrays and torch tensors of
any integer type (on any device); they work on the CPU with OpenCV, so each label image becomes
one contiguous uint8 H×W array here. The rule for ids is the confusion matrix's: ground truth
holds class ids in ``[0, K)`` or the ignore index (255); a prediction holds class ids in
``[0, K)`` wherever the ground truth is not ignored (what it holds under ignored pixels does not
count). Anything else raises a ``ValueError`` that lists the ids, never a silently shifted count.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from claravid.data.ignore import IGNORE_INDEX


def as_numpy(array: Any) -> np.ndarray:
    """A numpy view or copy of a numpy array or a torch tensor (moved to the CPU)."""
    if hasattr(array, "detach"):  # a torch tensor, without importing torch for numpy callers
        array = array.detach().cpu().numpy()
    return np.asarray(array)


def label_image(array: Any, name: str) -> np.ndarray:
    """``array`` as a contiguous uint8 H×W image.

    Raises:
        ValueError: not 2-D, not integers, or ids that fit no byte (no palette has them).
    """
    ids = as_numpy(array)
    if ids.ndim != 2:
        raise ValueError(f"{name} must be one H×W label image, got shape {tuple(ids.shape)}")
    if ids.dtype == np.uint8:
        return np.ascontiguousarray(ids)
    if ids.dtype.kind not in "iub":
        raise ValueError(f"{name} must hold integer class ids, got dtype {ids.dtype}")
    if ids.dtype == bool:
        return ids.astype(np.uint8)
    if ids.size and (int(ids.min()) < 0 or int(ids.max()) > 255):
        bad = np.unique(ids[(ids < 0) | (ids > 255)])[:8].tolist()
        raise ValueError(
            f"{name} holds ids {bad}, outside the palette's classes and the ignore index "
            f"{IGNORE_INDEX}"
        )
    return ids.astype(np.uint8)


def check_ids(
    truth: np.ndarray, prediction: np.ndarray | None, num_classes: int, name: str
) -> np.ndarray:
    """Raise if ``truth`` or (where ``truth`` counts) ``prediction`` holds an unknown id.

    Args:
        truth: uint8 ground truth (255 ignored).
        prediction: uint8 prediction of the same shape, or None to check the truth alone.
        num_classes: K.
        name: how the error names the image (``""``, ``"frame t's"``...).

    Returns:
        The valid pixels: uint8, 255 where the truth is not the ignore index.
    """
    prefix = f"{name} " if name else ""
    if truth.size == 0:  # OpenCV refuses empty arrays; nothing to check, nothing valid
        return np.zeros(truth.shape, np.uint8)
    if truth.size == 1:  # OpenCV reads a 1x1 array as a scalar and refuses scalar op scalar
        return _one_pixel(truth, prediction, num_classes, prefix)
    # OpenCV takes a scalar operand; its stubs want an array.
    valid = cv2.compare(truth, IGNORE_INDEX, cv2.CMP_NE)  # type: ignore[call-overload]
    # The largest id that counts first (one masked pass each); which ids are wrong is only
    # worked out when some are.
    if truth.size and num_classes < IGNORE_INDEX and cv2.minMaxLoc(truth, valid)[1] >= num_classes:
        bad = np.unique(truth[(truth >= num_classes) & (truth != IGNORE_INDEX)])
        _raise_outside(f"{prefix}ground truth", bad.tolist(), num_classes)
    if (
        prediction is not None
        and prediction.size
        and cv2.minMaxLoc(prediction, valid)[1] >= num_classes
    ):
        outside = cv2.bitwise_and(cv2.inRange(prediction, num_classes, 255), valid)
        _raise_outside(
            f"{prefix}prediction", np.unique(prediction[outside > 0]).tolist(), num_classes
        )
    return valid


def _one_pixel(
    truth: np.ndarray, prediction: np.ndarray | None, num_classes: int, prefix: str
) -> np.ndarray:
    """`check_ids` of a one-pixel image, in numpy."""
    valid = np.where(truth != IGNORE_INDEX, 255, 0).astype(np.uint8)
    if valid.any() and truth.item() >= num_classes:
        _raise_outside(f"{prefix}ground truth", [truth.item()], num_classes)
    if prediction is not None and valid.any() and prediction.item() >= num_classes:
        _raise_outside(f"{prefix}prediction", [prediction.item()], num_classes)
    return valid


def check_num_classes(num_classes: object) -> int:
    """K as an int in [1, 255] (ids and the ignore index share a byte)."""
    if isinstance(num_classes, bool) or not isinstance(num_classes, (int, np.integer)):
        raise ValueError(f"num_classes must be an integer, got {num_classes!r}")
    if not 1 <= num_classes <= IGNORE_INDEX:
        raise ValueError(f"num_classes must be in [1, {IGNORE_INDEX}], got {num_classes}")
    return int(num_classes)


def _raise_outside(name: str, bad: list[int], num_classes: int) -> None:
    raise ValueError(
        f"{name} holds ids {[int(b) for b in bad[:8]]} outside the palette's {num_classes} "
        f"classes (ignore index {IGNORE_INDEX})"
    )

"""The confusion of an image, and of each of its tiles: where predictions meet ground truth.

A confusion matrix counts pixels whose ground truth is not the ignore index, rows = ground
truth, columns = prediction (:mod:`claravid.eval.analysis.metrics` turns it into IoU, mIoU
and pixel accuracy). The tiles of an image are :func:`claravid.dsp.tiles.tile_grid` of its
labels; their confusions sum to the image's.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from claravid.data.ignore import IGNORE_INDEX
from claravid.dsp.tiles import tile_grid


def confusion_matrix(
    prediction: torch.Tensor | np.ndarray,
    target: torch.Tensor | np.ndarray,
    num_classes: int,
) -> torch.Tensor:
    """Pixel confusion of one image or batch: int64 [K, K], rows = truth, columns = prediction.

    On a GPU: one ``bincount`` on the tensors' device. On the CPU (numpy arrays or CPU
    tensors), ids that fit in a byte are counted with OpenCV (a lookup, a fused index and one
    histogram, about 15× faster than torch's CPU bincount on a 12-Mpixel frame).

    Args:
        prediction: predicted train ids, any integer shape.
        target: ground-truth train ids of the same shape; pixels of
            :data:`~claravid.eval.analysis.metrics.IGNORE_INDEX` (255, the one ignore id every
            palette uses) are skipped.
        num_classes: K.

    Raises:
        ValueError: shapes differ, or an id outside ``[0, K)`` (other than the ignore index in
            the ground truth) appears, which would silently shift the counts.
    """
    if tuple(prediction.shape) != tuple(target.shape):
        raise ValueError(
            f"prediction {tuple(prediction.shape)} and ground truth {tuple(target.shape)} differ "
            "in shape"
        )
    on_cpu = all(
        not isinstance(a, torch.Tensor) or a.device.type == "cpu" for a in (prediction, target)
    )
    if on_cpu and num_classes < 255:
        pred = _as_uint8(prediction)
        truth = _as_uint8(target)
        if pred is not None and truth is not None:
            return torch.from_numpy(_confusion_uint8(pred, truth, num_classes))
    prediction = torch.as_tensor(prediction)
    target = torch.as_tensor(target, device=prediction.device)
    target = target.reshape(-1).long()
    prediction = prediction.reshape(-1).long()
    valid = target != IGNORE_INDEX
    target, prediction = target[valid], prediction[valid]
    for name, ids in (("ground truth", target), ("prediction", prediction)):
        if ids.numel() and (int(ids.min()) < 0 or int(ids.max()) >= num_classes):
            bad = ids[(ids < 0) | (ids >= num_classes)].unique()[:8].tolist()
            _raise_outside(name, bad, num_classes)
    counts = torch.bincount(target * num_classes + prediction, minlength=num_classes**2)
    return counts.reshape(num_classes, num_classes)


def _raise_outside(name: str, bad: list[int], num_classes: int) -> None:
    raise ValueError(
        f"{name} holds ids {bad} outside the palette's {num_classes} classes "
        f"(ignore index {IGNORE_INDEX})"
    )


def _as_uint8(ids: torch.Tensor | np.ndarray) -> np.ndarray | None:
    """A contiguous 2-D uint8 view/copy of integer ids in [0, 255], or None when they do not fit."""
    array = ids.numpy() if isinstance(ids, torch.Tensor) else np.asarray(ids)
    if array.dtype != np.uint8:
        if array.dtype.kind not in "iu" or array.size == 0:
            return None
        if int(array.min()) < 0 or int(array.max()) > 255:
            return None
        array = array.astype(np.uint8)
    # OpenCV wants 2-D images: any shape is flattened to rows (the counts do not care).
    return np.ascontiguousarray(array.reshape(1, -1) if array.ndim != 2 else array)


def _confusion_uint8(pred: np.ndarray, truth: np.ndarray, num_classes: int) -> np.ndarray:
    k = num_classes
    if pred.size == 0:
        return np.zeros((k, k), dtype=np.int64)
    top = int(pred.max())
    if top >= k:  # only an error where the truth is not ignored
        bad = np.unique(pred[(truth != IGNORE_INDEX) & (pred >= k)])[:8].tolist()
        if bad:
            _raise_outside("prediction", bad, k)
    # Fused index = base[truth] + prediction: class c starts row c * k; the ignore index and
    # ids outside the palette get ranges past the K×K cells, the latter counted to be reported.
    if top < k and k * k + 2 * k <= 256:
        # Every prediction is valid: the index fits in a byte, and a byte histogram is ~5× faster.
        ignored, outside, span, dtype, depth = k * k, k * k + k, k, np.uint8, cv2.CV_8U
    else:
        # 256-wide ranges: no prediction id (junk under ignored pixels) can spill into a cell.
        ignored, outside, span, dtype, depth = k * k, k * k + 256, 256, np.uint16, cv2.CV_16U
    base = np.full(256, outside, dtype=dtype)
    base[:k] = np.arange(k, dtype=dtype) * k
    base[IGNORE_INDEX] = ignored
    bins = outside + span
    if pred.size < 1 << 24:  # float32 histogram counts are exact below 2^24
        index = cv2.add(cv2.LUT(truth, base), pred, dtype=depth)
        counts = cv2.calcHist([index], [0], None, [bins], [0, bins]).ravel().astype(np.int64)
    else:
        counts = np.bincount((base[truth].astype(np.int64) + pred).ravel(), minlength=bins)
    if counts[outside:].any():
        bad = np.unique(truth[(truth != IGNORE_INDEX) & (truth >= k)])[:8].tolist()
        _raise_outside("ground truth", bad, k)
    return counts[: k * k].reshape(k, k)


def tile_confusions(
    prediction: torch.Tensor | np.ndarray,
    target: torch.Tensor | np.ndarray,
    num_classes: int,
    size: int,
) -> np.ndarray:
    """The confusion of every tile of one image: int64 [rows, cols, K, K].

    The grid is :func:`claravid.dsp.tiles.tile_grid` of the ground truth's [H, W]; summed over
    the tiles it is the image's confusion.
    """
    if tuple(prediction.shape) != tuple(target.shape):
        raise ValueError(
            f"prediction {tuple(prediction.shape)} and ground truth {tuple(target.shape)} differ "
            "in shape"
        )
    ys, xs = tile_grid(tuple(target.shape), size)
    out = np.empty((len(ys) - 1, len(xs) - 1, num_classes, num_classes), dtype=np.int64)
    for r in range(len(ys) - 1):
        for c in range(len(xs) - 1):
            window = (slice(ys[r], ys[r + 1]), slice(xs[c], xs[c + 1]))
            conf = confusion_matrix(prediction[window], target[window], num_classes)
            out[r, c] = conf.cpu().numpy()
    return out


def image_confusion(
    prediction: torch.Tensor | np.ndarray,
    target: torch.Tensor | np.ndarray,
    num_classes: int,
    tile_size: int | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """An image's confusion (int64 [K, K]) and, with ``tile_size``, its tiles' confusions.

    The tiles cover every pixel once, so their sum is the image's confusion: counted once.
    """
    if tile_size is None:
        conf = confusion_matrix(prediction, target, num_classes)
        return conf.cpu().numpy(), None
    tiles = tile_confusions(prediction, target, num_classes, tile_size)
    return tiles.sum(axis=(0, 1)), tiles

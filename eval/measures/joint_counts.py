"""Joint counts of two byte images: a 256×256 table of how many pixels hold each pair of bytes.

The per-image measures beyond mIoU reduce to such tables (Boundary IoU of (truth key, prediction
key), cross-view consistency of (t's label, s's label carried back)), so counting pairs is a
large share of their time on a 12-Mpixel frame. OpenCV's 2-D histogram counts them (numpy past
2^24 pixels, where its float32 counts stop being exact): the same integers either way. A C pass
of our own that counted runs of one pair at once saved about 20 ms a frame, against seconds of
inference, and was removed.
"""

from __future__ import annotations

import cv2
import numpy as np


def joint_counts(
    first: np.ndarray, second: np.ndarray, channel: int = 0, out: np.ndarray | None = None
) -> np.ndarray:
    """int64 [256, 256]: entry (a, b) counts the pixels where ``first`` is a and ``second`` b.

    Args:
        first: uint8 H×W.
        second: uint8 H×W, or H×W×2 (two interleaved channels, of which ``channel`` counts:
            read in place, not split).
        channel: 0 or 1, the channel of a two-channel ``second``.
        out: a C-contiguous int64 [256, 256] table to add the counts to (an image counted in
            parts); a new one when None.

    Raises:
        ValueError: not uint8, not of one size, or no such channel.
    """
    channels = second.shape[2] if second.ndim == 3 else 1
    if (
        first.dtype != np.uint8
        or second.dtype != np.uint8
        or first.ndim != 2
        or second.shape[:2] != first.shape
        or second.ndim not in (2, 3)
        or channels not in (1, 2)
        or not 0 <= channel < channels
    ):
        raise ValueError(
            f"joint counts take two uint8 images of one shape (the second H×W or H×W×2 with "
            f"channel 0 or 1), got {first.dtype} {first.shape} and {second.dtype} "
            f"{second.shape}, channel {channel}"
        )
    if out is None:
        out = np.zeros((256, 256), np.int64)
    elif out.dtype != np.int64 or out.shape != (256, 256) or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous int64 256×256 table, got {out.dtype} "
                         f"{out.shape}")  # fmt: skip
    out += _counts(first, second, channel)
    return out


def _counts(first: np.ndarray, second: np.ndarray, channel: int) -> np.ndarray:
    """The table with OpenCV (numpy for 2^24 pixels and more)."""
    if first.size < 1 << 24:  # float32 histogram counts are exact below 2^24
        # The full 256×256 byte histogram: OpenCV's fastest (narrower ranges take a slow path).
        pair = [np.ascontiguousarray(first), np.ascontiguousarray(second)]
        joint = cv2.calcHist(pair, [0, 1 + channel], None, [256, 256], [0, 256, 0, 256])
        return joint.astype(np.int64)
    other = second[..., channel] if second.ndim == 3 else second
    index = first.astype(np.int64) * 256 + other
    return np.bincount(index.ravel(), minlength=1 << 16).reshape(256, 256)

"""Where a pair of frames agrees, pixel by pixel, for the picture of the hardest-images sheet.

The pair's numbers are :func:`claravid.eval.measures.cross_view.cross_view`'s sums; the sheet
marks, on a thumbnail of frame t, which of its pixels are kept and whether the predictions of t
and s agree there. Each thumbnail pixel centre is carried to s with the camera model of
:mod:`claravid.io.layout` (its depth, t's pose, s's pose, the intrinsics scaled to the
thumbnail) and kept by the same rules: a depth hit, static and labelled in both frames, inside
s and visible there (the depth test with ``cross_view``'s tolerance).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from claravid.eval.measures.cross_view import TOLERANCE
from claravid.io.layout import DEPTH_MAX_M, DYNAMIC_MASK_STATIC, camera_points, world_to_image

IGNORE = 255


def pair_marks(
    t: Any,
    s: Any,
    pred_t: np.ndarray,
    pred_s: np.ndarray,
    gt_t: np.ndarray,
    gt_s: np.ndarray,
    size: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Frame t's kept pixels and, among them, those whose predictions agree with s: bool
    arrays of ``size`` = (width, height), a thumbnail of t.

    Args:
        t, s: the frames' geometry (``depth``, ``c2w``, ``dynamic``, ``intrinsics`` at full
            size, :class:`~claravid.eval.inputs.pairs.FrameGeometry`).
        pred_t, pred_s, gt_t, gt_s: full-size labels (uint8 [H, W]).
        size: the thumbnail's (width, height).
    """
    height, width = t.depth.shape

    def small(image: np.ndarray) -> np.ndarray:
        return cv2.resize(image, size, interpolation=cv2.INTER_NEAREST)

    depth_t = small(t.depth)
    intrinsics = np.asarray(t.intrinsics, np.float64).copy()
    intrinsics[0] *= size[0] / width
    intrinsics[1] *= size[1] / height
    world = camera_points(depth_t, intrinsics) @ t.c2w[:3, :3].T + t.c2w[:3, 3]
    projection = world_to_image(s.c2w, s.intrinsics)
    q = world @ projection[:, :3].T + projection[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
    inside = (q[..., 2] > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    col = np.clip(np.nan_to_num(np.floor(u)), 0, width - 1).astype(np.int64)
    row = np.clip(np.nan_to_num(np.floor(v)), 0, height - 1).astype(np.int64)
    seen = s.depth[row, col]
    kept = inside & _usable(depth_t, small(t.dynamic), small(gt_t))
    kept &= _usable(seen, s.dynamic[row, col], gt_s[row, col])
    kept &= np.abs(seen - q[..., 2]) <= TOLERANCE * q[..., 2]
    agree = kept & (small(pred_t) == pred_s[row, col])
    return kept, agree


def _usable(depth: np.ndarray, dynamic: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """A depth hit (0 < d < 1000 m), static and labelled."""
    return (depth > 0) & (depth < DEPTH_MAX_M) & (dynamic == DYNAMIC_MASK_STATIC) & (gt != IGNORE)

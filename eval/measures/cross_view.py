"""Cross-view consistency of one pair of frames, from exact depth and poses (no optical flow).

ClaraVid gives every frame metric depth, a camera-to-world pose and the intrinsics, so the pixel
of the next frame of a pass that sees the same 3D point is known exactly. For frame t and the
next frame s of its pass, each pixel centre (u, v) of t with depth d is carried to s
(:mod:`claravid.io.layout` has the axes and the projection: OpenGL camera axes, pixel centres at
integer + 0.5): camera point ``(x, y, z) = ((u − cx)·d/fx, −(v − cy)·d/fy, −d)``, world point
``c2w_t · (x, y, z, 1)``, and in s its depth ``d_s`` and pixel ``(u_s, v_s)``. The pixel is
*kept* when

- its depth is a hit (``0 < d < 1000`` m: 0 and 1000 m are sky or nothing), it is static (dynamic
  mask 255) and its ground truth is not the ignore index;
- ``d_s > 0`` and ``(u_s, v_s)`` lies inside s; the pixel of s whose centre is nearest to it is
  static, has a depth hit and a ground truth that is not ignored;
- the point is visible in s, not hidden behind something: ``|depth_s − d_s| ≤ τ · d_s`` at that
  pixel (τ = 0.01).

Over the kept pixels a pair stores sums, like a confusion matrix: how many, how many whose
predictions agree (the prediction of t against the prediction of s carried back), and per class
the intersection and union of ``pred_t == c`` and ``carried pred_s == c`` (VSPW's temporal
consistency, with geometry in place of optical flow); the same for the ground truth, whose
consistency is the ceiling (≈ 1 on correct data: it checks depth, poses and the projection).
A pair whose kept pixels are under 10 % of the frame (a turn at the end of a pass, or frames
that barely overlap) is skipped, as is a pair of identical poses (s shows what t shows); a pair
whose files are missing is unavailable (:mod:`claravid.eval.inputs.pairs` reads them).
Skipped and unavailable pairs say why.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from claravid.data.ignore import IGNORE_INDEX
from claravid.eval.measures.joint_counts import joint_counts
from claravid.eval.measures.label_ids import as_numpy, check_ids, check_num_classes, label_image
from claravid.io.layout import (
    DEPTH_MAX_M,
    DYNAMIC_MASK_STATIC,
    PIXEL_CENTRE,
    pixel_to_camera,
    rigid_error,
    world_to_image,
)

#: Visibility tolerance: the carried depth may differ from s's own by this fraction.
TOLERANCE = 0.01
#: A pair counts when its kept pixels are at least this fraction of frame t.
MIN_KEPT = 0.10
#: Poses closer than this (every entry, metres or rotation) are the same pose.
SAME_POSE = 1e-6

_BAND_PIXELS = 1 << 16  # rows carried at a time: the band's arrays stay in the CPU's cache


@dataclass(frozen=True)
class CrossViewSums:
    """One pair's sums (frame t and the next frame s of its pass).

    Attributes:
        status: ``"ok"`` (the pair counts), ``"skipped"`` (too little overlap, identical poses)
            or ``"unavailable"`` (depth or poses missing).
        reason: why it is skipped or unavailable; empty when ok.
        pixels: pixels of frame t.
        kept: pixels of t carried to s and kept (see the module's conditions).
        agree: kept pixels whose prediction in t equals the carried prediction of s.
        intersection, union: int64 [K], per class c, over the kept pixels,
            ``|pred_t == c ∩ carried pred_s == c|`` and ``|pred_t == c ∪ carried pred_s == c|``.
        gt_agree, gt_intersection, gt_union: the same for the ground truth (the ceiling).
    """

    status: str
    reason: str
    pixels: int
    kept: int
    agree: int
    intersection: np.ndarray = field(repr=False)
    union: np.ndarray = field(repr=False)
    gt_agree: int
    gt_intersection: np.ndarray = field(repr=False)
    gt_union: np.ndarray = field(repr=False)

    @property
    def counted(self) -> bool:
        """Whether the pair's sums belong in a group's totals."""
        return self.status == "ok"

    @property
    def kept_fraction(self) -> float:
        """Kept pixels / pixels of frame t (NaN for an empty or unavailable pair)."""
        return self.kept / self.pixels if self.pixels else float("nan")

    @property
    def consistency(self) -> float:
        """Agreeing / kept pixels of the predictions (NaN when nothing is kept)."""
        return self.agree / self.kept if self.kept else float("nan")

    @property
    def gt_consistency(self) -> float:
        """Agreeing / kept pixels of the ground truth: the ceiling (NaN when nothing is kept)."""
        return self.gt_agree / self.kept if self.kept else float("nan")

    @classmethod
    def unavailable(cls, reason: str, num_classes: int) -> CrossViewSums:
        """A pair that could not be measured, with the reason (e.g. which file is missing)."""
        zeros = np.zeros(num_classes, np.int64)
        return cls("unavailable", reason, 0, 0, 0, zeros, zeros, 0, zeros, zeros)


def _one_pixel(
    frames: tuple[Any, ...],
    labels: dict[str, np.ndarray],
    k: int,
    tolerance: float,
    min_kept: float,
) -> CrossViewSums:
    """A 1x1 pair measured as 1x2: the added pixel has no depth hit, is ignored and moving, so
    it is never kept nor looked up; twice the pixels halve the kept fraction, so ``min_kept``
    halves too."""
    depth_t, depth_s, c2w_t, c2w_s, intrinsics, dynamic_t, dynamic_s = frames
    d_t, d_s = _beside(depth_t, 0), _beside(depth_s, 0)
    p_t, p_s = _beside(labels["pred_t"], 0), _beside(labels["pred_s"], 0)
    g_t, g_s = _beside(labels["gt_t"], IGNORE_INDEX), _beside(labels["gt_s"], IGNORE_INDEX)
    m_t = None if dynamic_t is None else _beside(as_numpy(dynamic_t), 0)
    m_s = None if dynamic_s is None else _beside(as_numpy(dynamic_s), 0)
    padded = cross_view(d_t, d_s, c2w_t, c2w_s, intrinsics, p_t, p_s, g_t, g_s, m_t, m_s,
                        num_classes=k, tolerance=tolerance, min_kept=min_kept / 2)  # fmt: skip
    return dataclasses.replace(padded, pixels=1)


def _joint_sums(pred_joint: np.ndarray, gt_joint: np.ndarray, pixels: int) -> dict[str, Any]:
    """The pair's sums from the K×K counts of (t, s) predictions and ground truths over the kept
    pixels: agreement and per-class intersection and union of each."""
    inter, gt_inter = np.diagonal(pred_joint).copy(), np.diagonal(gt_joint).copy()
    return dict(
        pixels=pixels,
        kept=int(gt_joint.sum()),
        agree=int(inter.sum()),
        intersection=inter,
        union=pred_joint.sum(axis=1) + pred_joint.sum(axis=0) - inter,
        gt_agree=int(gt_inter.sum()),
        gt_intersection=gt_inter,
        gt_union=gt_joint.sum(axis=1) + gt_joint.sum(axis=0) - gt_inter,
    )


def cross_view(
    depth_t: Any,
    depth_s: Any,
    c2w_t: Any,
    c2w_s: Any,
    K: Any,
    pred_t: Any,
    pred_s: Any,
    gt_t: Any,
    gt_s: Any,
    dynamic_t: Any = None,
    dynamic_s: Any = None,
    *,
    num_classes: int,
    tolerance: float = TOLERANCE,
    min_kept: float = MIN_KEPT,
) -> CrossViewSums:
    """The cross-view sums of frame t and the next frame s of its pass.

    Args:
        depth_t, depth_s: planar depth in metres, H×W (as ``read_depth`` gives it).
        c2w_t, c2w_s: camera-to-world 4×4 poses, OpenGL camera axes (as ``read_extrinsics``).
        K: 3×3 intrinsics of both frames at H×W (``scaled_intrinsics((W, H))``).
        pred_t, pred_s: predicted class ids, H×W.
        gt_t, gt_s: ground-truth class ids, H×W; 255 is ignored.
        dynamic_t, dynamic_s: dynamic masks as read (uint8, 255 static, 0 dynamic), or None
            when nothing moves.
        num_classes: K classes of the ids.
        tolerance: τ of the visibility test.
        min_kept: the kept fraction of frame t under which the pair is skipped.

    All arrays may be numpy arrays or torch tensors.

    Raises:
        ValueError: shapes that differ, a pose that is not a rigid transform, intrinsics that
            are not a pinhole matrix, a dynamic mask of booleans, or unknown class ids.
    """
    k = check_num_classes(num_classes)
    depth_t, depth_s = _depth(depth_t, "depth_t"), _depth(depth_s, "depth_s")
    shape = depth_t.shape
    c2w_t, c2w_s = _pose(c2w_t, "c2w_t"), _pose(c2w_s, "c2w_s")
    intrinsics = _intrinsics(K)
    labels = {
        name: label_image(array, name)
        for name, array in (("pred_t", pred_t), ("pred_s", pred_s), ("gt_t", gt_t), ("gt_s", gt_s))
    }
    static_t, static_s = (
        _static(dynamic_t, "dynamic_t", shape),
        _static(dynamic_s, "dynamic_s", shape),
    )
    for name, array in (*labels.items(), ("depth_s", depth_s)):
        if array.shape != shape:
            raise ValueError(f"{name} is {array.shape} but depth_t is {shape}: give one frame size")
    valid_t = check_ids(labels["gt_t"], labels["pred_t"], k, "frame t's")
    valid_s = check_ids(labels["gt_s"], labels["pred_s"], k, "frame s's")
    if not 0 < tolerance < 1 or not 0 <= min_kept <= 1:
        raise ValueError(f"tolerance must be in (0, 1) and min_kept in [0, 1], got "
                         f"{tolerance}, {min_kept}")  # fmt: skip
    pixels = shape[0] * shape[1]
    if pixels == 1:  # OpenCV reads a 1x1 array as a scalar: add a pixel that never counts
        frames = (depth_t, depth_s, c2w_t, c2w_s, intrinsics, dynamic_t, dynamic_s)
        return _one_pixel(frames, labels, k, tolerance, min_kept)
    zeros = np.zeros(k, np.int64)
    if np.abs(c2w_t - c2w_s).max() <= SAME_POSE:
        return CrossViewSums(
            "skipped", "identical poses: frame s shows what frame t shows (consistency would be "
            "trivially 1)", pixels, 0, 0, zeros, zeros, 0, zeros, zeros,
        )  # fmt: skip

    # Pixels of t that can be kept: a depth hit, static, not ignored.
    hits = _hits(depth_t)
    valid_t = cv2.bitwise_and(valid_t, hits, dst=valid_t)
    if static_t is not None:
        valid_t = cv2.bitwise_and(valid_t, static_t, dst=valid_t)
    # Pixels of s that can be looked up: the same, folded into its labels (255: never kept; a
    # carried 255 falls outside the K×K counts).
    usable_s = cv2.bitwise_and(valid_s, _hits(depth_s, dst=hits), dst=valid_s)
    if static_s is not None:
        usable_s = cv2.bitwise_and(usable_s, static_s, dst=usable_s)
    labels_s = cv2.merge([labels["pred_s"], labels["gt_s"]])
    # OpenCV takes a scalar operand; its stubs want an array.
    cv2.bitwise_or(labels_s, (255, 255, 0, 0), dst=labels_s,  # type: ignore[call-overload]
                   mask=cv2.bitwise_not(usable_s, dst=usable_s))  # fmt: skip
    pred_joint, gt_joint = _carry(
        _transfer(c2w_t, c2w_s, intrinsics), depth_t, valid_t, depth_s, labels_s,
        labels["pred_t"], labels["gt_t"], np.float32(tolerance), k,
    )  # fmt: skip
    sums = _joint_sums(pred_joint, gt_joint, pixels)
    kept = sums["kept"]
    if kept < min_kept * pixels:
        reason = (
            f"{kept} pixels kept, {100 * kept / pixels:.1f}% of the frame, under the "
            f"{100 * min_kept:g}% a pair needs (a turn at the end of a pass, or frames that "
            "barely overlap)"
        )
        return CrossViewSums("skipped", reason, **sums)
    return CrossViewSums("ok", "", **sums)


def _transfer(c2w_t: np.ndarray, c2w_s: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """T (float64 3×4) with ``T · (d·u, d·v, d, 1) = d_s · (x_s, y_s, 1)``.

    (u, v) are pixel *indices* of t (centres at u + 0.5), (x_s, y_s) the coordinates of s that
    ``cv2.remap`` rounds to the nearest pixel (centres at integers), and d_s the depth in s.
    """
    to_camera = pixel_to_camera(intrinsics)  # d·A·(u + ½, v + ½, 1) = camera point of t
    centre = np.array([[1.0, 0, PIXEL_CENTRE], [0, 1.0, PIXEL_CENTRE], [0, 0, 1.0]])
    to_index = np.array([[1.0, 0, -PIXEL_CENTRE], [0, 1.0, -PIXEL_CENTRE], [0, 0, 1.0]])
    project = to_index @ world_to_image(c2w_s, intrinsics) @ c2w_t  # camera t point -> s
    out = np.empty((3, 4))
    out[:, :3] = project[:, :3] @ to_camera @ centre
    out[:, 3] = project[:, 3]
    return out


def _carry(
    transfer: np.ndarray,
    depth_t: np.ndarray,
    valid_t: np.ndarray,
    depth_s: np.ndarray,
    labels_s: np.ndarray,
    pred_t: np.ndarray,
    gt_t: np.ndarray,
    tolerance: np.float32,
    num_classes: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint counts (int64 K×K) over the kept pixels of (t, carried s): predictions, truth."""
    height, width = depth_t.shape
    rows_per_band = max(1, _BAND_PIXELS // width)
    visible = visible_range(tolerance)
    m = transfer.astype(np.float32)
    cols = np.arange(width, dtype=np.float32)
    along = [m[i, 0] * cols for i in range(3)]  # the column part of M · (u, v, 1)
    # Band-sized buffers, written in place band after band (they stay in the CPU's cache), and
    # the two joint counts, added to band after band.
    q_all = np.empty((3, rows_per_band, width), np.float32)
    keys_all = np.empty((2, rows_per_band, width), np.uint8)  # t's labels, 255 unless kept
    carried_all = np.empty((rows_per_band, width, 2), np.uint8)  # s's labels, carried back
    # The two labels of a pixel move as one 16-bit value (OpenCV's one-channel remap is faster
    # than its two-channel one); the bytes come back in their order whatever the endianness.
    pairs_s, pairs_carried = labels_s.view(np.uint16)[..., 0], carried_all.view(np.uint16)[..., 0]
    pred_joint, gt_joint = np.zeros((256, 256), np.int64), np.zeros((256, 256), np.int64)
    for r0 in range(0, height, rows_per_band):
        band = slice(r0, min(height, r0 + rows_per_band))
        n = band.stop - band.start
        d = depth_t[band]
        rows = np.arange(band.start, band.stop, dtype=np.float32)[:, None]
        # q = d · (M · (u, v, 1)) + h, row by row of M; q[2] is the depth in s.
        q = q_all[:, :n]
        for i in range(3):
            np.add(along[i], m[i, 1] * rows + m[i, 2], out=q[i])
            q[i] *= d
            q[i] += m[i, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = np.divide(np.float32(1), q[2], out=q[2])
            x, y = np.multiply(q[0], inverse, out=q[0]), np.multiply(q[1], inverse, out=q[1])
            # Nearest pixel of s (NaN or far outside: remap's border), looked up twice.
            near, _ = cv2.convertMaps(x, y, cv2.CV_16SC2, nninterpolation=True)
            # OpenCV takes map2 None beside a CV_16SC2 map1; its stubs want an array.
            looked = cv2.remap(depth_s, near, None, cv2.INTER_NEAREST, dst=x,  # type: ignore[call-overload]
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)  # fmt: skip
            # Visible: |depth_s − d_s| <= τ·d_s, i.e. |depth_s / d_s − 1| <= τ (one range test,
            # see visible_range); this also needs d_s > 0 (s's unusable pixels carry label 255,
            # counted nowhere).
            looked *= inverse
        kept = cv2.inRange(looked, *visible)
        kept = cv2.bitwise_and(kept, valid_t[band], dst=kept)
        carried = carried_all[:n]
        cv2.remap(pairs_s, near, None, cv2.INTER_NEAREST, dst=pairs_carried[:n],  # type: ignore[call-overload]
                  borderMode=cv2.BORDER_CONSTANT, borderValue=0xFFFF)  # fmt: skip
        dropped = cv2.bitwise_not(kept, dst=kept)
        keys = keys_all[:, :n]
        cv2.bitwise_or(pred_t[band], dropped, dst=keys[0])  # kept ids are < K
        cv2.bitwise_or(gt_t[band], dropped, dst=keys[1])
        joint_counts(keys[0], carried, 0, out=pred_joint)
        joint_counts(keys[1], carried, 1, out=gt_joint)
    k = num_classes
    return pred_joint[:k, :k], gt_joint[:k, :k]


def visible_range(tolerance: np.float32) -> tuple[float, float]:
    """``[lo, hi]``: the float32 ratios r with ``|r − 1| <= τ`` as float32 arithmetic has it.

    The rounded ``|r − 1|`` grows as r moves away from 1 on either side, so the ratios that pass
    are one interval; walking from ``1 ± τ`` to its ends, float32 by float32, finds it, and one
    range test per pixel then decides as the subtraction and comparison would.
    """
    one, up, down = np.float32(1), np.float32(np.inf), np.float32(0)

    def passes(r: np.float32) -> bool:
        return bool(np.abs(r - one) <= tolerance)

    ends = []
    for start, outward in ((one - tolerance, down), (one + tolerance, up)):
        end = np.float32(start)
        while not passes(end):
            end = np.nextafter(end, one)
        while passes(np.nextafter(end, outward)):
            end = np.nextafter(end, outward)
        ends.append(float(end))
    return ends[0], ends[1]


def _hits(depth: np.ndarray, dst: np.ndarray | None = None) -> np.ndarray:
    """255 where the depth is a hit: 0 < d < 1000 m (0 and 1000 m are nothing and sky)."""
    # One integer pass: a non-negative float32's bits order as the floats do, and -0.0,
    # negatives and NaNs fall outside [1, bits(1000 m) − 1] (no float compare, no denormal mode).
    return cv2.inRange(depth.view(np.int32), 1, _BELOW_MAX_BITS, dst=dst)


_BELOW_MAX_BITS = int(np.float32(DEPTH_MAX_M).view(np.int32)) - 1


def _depth(array: Any, name: str) -> np.ndarray:
    depth = as_numpy(array)
    if depth.ndim != 2 or depth.dtype.kind != "f":
        raise ValueError(f"{name} must be H×W depths in metres (float), got {depth.dtype} "
                         f"{tuple(depth.shape)}")  # fmt: skip
    return np.ascontiguousarray(depth, dtype=np.float32)


def _pose(array: Any, name: str) -> np.ndarray:
    pose = as_numpy(array).astype(np.float64)
    problem = rigid_error(pose)
    if problem is not None:
        raise ValueError(f"{name} is not a camera pose: {problem}")
    return pose


def _intrinsics(array: Any) -> np.ndarray:
    k = as_numpy(array).astype(np.float64)
    if (
        k.shape != (3, 3)
        or not np.isfinite(k).all()
        or not (k[0, 0] > 0 and k[1, 1] > 0)
        or np.abs(k[2] - (0, 0, 1)).max() > 1e-9
        or k[1, 0] != 0
    ):
        raise ValueError(
            f"K must be pinhole intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}"
        )
    return k


def _beside(array: np.ndarray, value: float) -> np.ndarray:
    """A 1x1 frame with a second pixel of ``value`` to its right (1x2)."""
    return np.concatenate([array, np.full_like(array, value)], axis=1)


def _static(array: Any, name: str, shape: tuple[int, int]) -> np.ndarray | None:
    """255 where static, from a dynamic mask as read (uint8: 255 static, 0 dynamic)."""
    if array is None:
        return None
    mask = as_numpy(array)
    if mask.dtype != np.uint8:
        raise ValueError(
            f"{name} must be the dynamic mask as read (uint8: 255 static, 0 dynamic), got "
            f"{mask.dtype}; for a boolean 'moving' array pass np.where(moving, 0, 255)"
        )
    if mask.shape != shape:
        raise ValueError(f"{name} is {mask.shape} but depth_t is {shape}: give one frame size")
    if mask.size and int(mask.max()) == 1:  # 0/1: no file holds it; 1 would read as moving
        raise ValueError(
            f"{name} holds 0 and 1, not the 0/255 of the dynamic mask as read (255 static, 0 "
            f"dynamic): pass np.where(mask == 1, 255, 0).astype(np.uint8) if 1 means static, "
            f"np.where(mask == 1, 0, 255).astype(np.uint8) if 1 means moving"
        )
    if mask.size == 1:  # OpenCV reads a 1x1 array as a scalar
        return np.where(mask == DYNAMIC_MASK_STATIC, 255, 0).astype(np.uint8)
    # OpenCV takes a scalar operand; its stubs want an array.
    return cv2.compare(mask, DYNAMIC_MASK_STATIC, cv2.CMP_EQ)  # type: ignore[call-overload]

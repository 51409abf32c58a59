"""Cross-view pairs of an evaluation: each frame t with the next frame s of its pass.

A pass is the sorted stems of one viewpoint folder (``<mission>/<modality>/<viewpoint>/``); the
frames of the ClaraVid selection (all splits) are listed once, so frame t's next frame is the
next stem on disk whether or not s is evaluated too. A pair belongs to its frame t: whoever
evaluates t measures the pair, reading s's prediction where it is at hand (the same run, a saved
label map) and predicting s otherwise (the last frame of a rank's shard, of a job-array part, of
a block of the split). So every pair is counted once, by one rank, and the parts of a job array
merge into exactly one run's sums.

The pair's sums are :func:`claravid.eval.measures.cross_view.cross_view` of the two frames'
depth, poses, intrinsics, predictions, ground truths and dynamic masks
(:func:`claravid.eval.inputs.pairs.read_geometry`); a frame without its depth PNG,
extrinsics or dynamic mask (a partial download), or with one of them damaged, makes its pairs
unavailable, with the reason, and nothing else changes.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.analysis.quality_table import (
    PAIR_IDENTICAL,
    PAIR_LAST,
    PAIR_OK,
    PAIR_TURN,
    PAIR_UNAVAILABLE,
    pair_columns,
)
from claravid.eval.inputs.datasets import EvalData
from claravid.io.layout import MISSIONS, MODALITIES

#: The files a pair reads of each frame besides its labels, by SDK field.
GEOMETRY_FIELDS = ("depth", "extrinsics", "dynamic_mask")


@dataclass
class PairResult:
    """One frame t's pair: the next frame's key, its status, the reason when not counted, the
    row of sums (:class:`~claravid.eval.analysis.quality_table.PairTable`), and the two frames'
    geometry (for the hardest-images sheet, dropped once offered)."""

    next: str
    status: str
    reason: str
    sums: np.ndarray
    geometry: tuple[Any, Any] | None = None


def pairs_unavailable(data: EvalData) -> str | None:
    """Why ``data`` has no cross-view pairs (None: it has them)."""
    if data.name != "claravid":
        kind = "UAVid" if data.name == "uavid" else "a folder of images"
        return f"{kind} has no depth or camera poses"
    raw = _claravid_images(data)
    roots = {Path(raw.root) / MISSIONS[f.mission] for f in raw.frames}
    for field in GEOMETRY_FIELDS:
        folder = MODALITIES[field].folder
        if not any((root / str(folder)).is_dir() for root in roots):
            return f"no {folder}/ folder in the evaluated missions (a partial download?)"
    if raw.frames and not any(PassFrames(data).next_key[f.key] for f in raw.frames):
        return (
            "no evaluated frame has a next frame in its pass (each pass of the selection holds "
            "one frame), so there is no pair of frames to compare"
        )
    return None


def _claravid_images(data: EvalData) -> ClaraVidSegmentation:
    """The ClaraVid dataset below ``data``'s keys (a claravid evaluation always has one)."""
    raw = data.dataset.dataset
    if not isinstance(raw, ClaraVidSegmentation):
        raise TypeError(f"cross-view pairs read ClaraVid frames, not a {type(raw).__name__}")
    return raw


class PassFrames:
    """Every frame of the passes a ClaraVid evaluation touches, and how to read each one.

    Args:
        data: the evaluation's ClaraVid images (a split of a selection).
        cache: frames whose geometry (depth, pose, dynamic mask) is kept, most recent first:
            consecutive pairs share a frame, read once.
    """

    def __init__(self, data: EvalData, cache: int = 4) -> None:
        raw = _claravid_images(data)
        chosen = data.describe.get("selection") or {}
        # The whole selection, every split: the next frame on disk is the next of the pass.
        self.frames = ClaraVidSegmentation(
            raw.root,
            split="all",
            missions=chosen.get("missions"),
            altitude=chosen.get("altitude"),
            direction=chosen.get("direction"),
            palette=raw.palette,
            label_cache=raw.label_cache is not None,
            mask_dtype=torch.uint8,
        )
        self.root = Path(raw.root)
        listed = self.frames.frames
        self.position = {f.key: j for j, f in enumerate(listed)}
        self.next_key = {
            f.key: (g.key if (g.mission, g.viewpoint) == (f.mission, f.viewpoint) else "")
            for f, g in zip(listed, [*listed[1:], listed[-1]], strict=True)
        }
        self.next_key[listed[-1].key] = ""
        self._cache: OrderedDict[str, Any] = OrderedDict()
        self._size = cache
        self._lock = threading.Lock()

    def next_of(self, key: str) -> str:
        """The key of the next frame of ``key``'s pass ("" for the last)."""
        return self.next_key[key]

    def mask(self, key: str) -> np.ndarray:
        """The labels of frame ``key`` (uint8 train ids, 255 ignored)."""
        return self.frames.read_mask(self.position[key])

    def image(self, key: str) -> torch.Tensor:
        """The RGB of frame ``key`` (uint8 [3, H, W])."""
        return self.frames[self.position[key]]["image"]

    def geometry(self, key: str) -> Any:
        """Frame ``key``'s depth, pose, dynamic mask and intrinsics
        (:class:`~claravid.eval.inputs.pairs.FrameGeometry`), or why they cannot be read (a
        file missing, or damaged: a PNG that does not decode, a pose that is not a rigid
        transform), naming the file: that frame's pairs are unavailable, nothing else."""
        from claravid.eval.inputs.pairs import GeometryUnavailable, read_geometry

        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        try:
            found: Any = read_geometry(self.root, self.frames.frames[self.position[key]])
        except GeometryUnavailable as exc:
            found = str(exc)
        with self._lock:
            self._cache[key] = found
            while len(self._cache) > self._size:
                self._cache.popitem(last=False)
        return found


def measure_pair(
    frames: PassFrames,
    key_t: str,
    pred_t: np.ndarray,
    gt_t: np.ndarray,
    pred_s: Callable[[str], np.ndarray | str],
    num_classes: int,
    keep_geometry: bool = False,
) -> PairResult:
    """Frame ``key_t``'s pair with the next frame of its pass.

    Args:
        frames: the passes.
        key_t: frame t.
        pred_t, gt_t: t's prediction and labels (uint8 [H, W]).
        pred_s: the prediction of a frame by its key, or why there is none.
        num_classes: K.
        keep_geometry: keep both frames' geometry in the result (the hardest-images sheet).
    """
    from claravid.eval.measures.cross_view import SAME_POSE, cross_view

    width = pair_columns(num_classes)
    key_s = frames.next_of(key_t)
    if not key_s:
        return PairResult("", PAIR_LAST, "", np.zeros(width, np.int64))
    t, s = frames.geometry(key_t), frames.geometry(key_s)
    prediction = pred_s(key_s)
    for found in (t, s, prediction):
        if isinstance(found, str):
            return PairResult(key_s, PAIR_UNAVAILABLE, found, np.zeros(width, np.int64))
    if np.abs(np.asarray(t.c2w, np.float64) - s.c2w).max() <= SAME_POSE:
        why = f"{key_t} and {key_s} have identical poses: their consistency would be 1"
        return PairResult(key_s, PAIR_IDENTICAL, why, np.zeros(width, np.int64))
    if t.depth.shape != s.depth.shape:
        why = f"{key_t} and {key_s} have depth maps of different sizes"
        return PairResult(key_s, PAIR_UNAVAILABLE, why, np.zeros(width, np.int64))
    out = cross_view(t.depth, s.depth, t.c2w, s.c2w, t.intrinsics, pred_t, prediction, gt_t,
                     frames.mask(key_s), t.dynamic, s.dynamic, num_classes=num_classes)  # fmt: skip
    if out.status == "unavailable":
        return PairResult(key_s, PAIR_UNAVAILABLE, out.reason, np.zeros(width, np.int64))
    if out.status != "ok":  # skipped: too few pixels kept (a turn)
        return PairResult(key_s, PAIR_TURN, "", np.zeros(width, np.int64))
    row = np.concatenate([[out.kept, out.agree, out.gt_agree], out.intersection, out.union,
                          out.gt_intersection, out.gt_union]).astype(np.int64)  # fmt: skip
    return PairResult(key_s, PAIR_OK, "", row, (t, s) if keep_geometry else None)

"""Cross-view pairs of an evaluation: each frame t with the next frame s of its pass.

A pass is the sorted stems of one viewpoint folder (``<mission>/<modality>/<viewpoint>/``); the
frames of the ClaraVid selection (all splits) are listed once, so frame t's next frame is the
next stem on disk whether or not s is evaluated too. A pair belongs to its frame t: whoever
evaluates t measures the pair, reading s's prediction where it is at hand (the same run, a saved
label map) and predicting s otherwise (the last frame of a rank's shard, of a job-array part, of
a block of the split). So every pair is counted once, by one rank, and the parts of a job array
merge into exactly one run's sums.

The pair's sums come from :func:`claravid.eval.inference.cross_view.cross_view` on the two
frames' depth, poses, intrinsics, predictions, ground truths and dynamic masks; a frame without
its depth PNG, extrinsics or dynamic mask (a partial download) makes its pairs unavailable,
with the reason, and nothing else changes.
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
from claravid.eval.inference.data import EvalData
from claravid.io import modalities
from claravid.io.layout import MISSIONS, frame_file

#: The files a pair reads of each frame besides its labels, by SDK field.
GEOMETRY_FIELDS = ("depth", "extrinsics", "dynamic_mask")


@dataclass
class PairResult:
    """One frame t's pair: its status, the reason when unavailable, the row of sums
    (:class:`~claravid.eval.analysis.quality_table.PairTable`), and, for the hardest-images
    sheet, t's kept and agreeing pixels (bool [H, W] each; None when not counted)."""

    next: str
    status: str
    reason: str
    sums: np.ndarray
    kept: np.ndarray | None = None
    agree: np.ndarray | None = None


def pairs_unavailable(data: EvalData) -> str | None:
    """Why ``data`` has no cross-view pairs (None: it has them)."""
    if data.name != "claravid":
        kind = "UAVid" if data.name == "uavid" else "a folder of images"
        return f"{kind} has no depth or camera poses"
    raw = data.dataset.dataset
    roots = {Path(raw.root) / MISSIONS[f.mission] for f in raw.frames}
    for field in GEOMETRY_FIELDS:
        folder = modalities_folder(field)
        if not any((root / folder).is_dir() for root in roots):
            return f"no {folder}/ folder in the evaluated missions (a partial download?)"
    return None


def modalities_folder(field: str) -> str:
    """The modality folder of an SDK field (``depth`` -> ``depth``, ``rgb`` -> ``left_rgb``)."""
    from claravid.io.layout import MODALITIES

    return str(MODALITIES[field].folder)


class PassFrames:
    """Every frame of the passes a ClaraVid evaluation touches, and how to read each one.

    Args:
        data: the evaluation's ClaraVid images (a split of a selection).
        cache: frames whose geometry (depth, pose, dynamic mask) is kept, most recent first:
            consecutive pairs share a frame, read once.
    """

    def __init__(self, data: EvalData, cache: int = 4) -> None:
        raw: ClaraVidSegmentation = data.dataset.dataset
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

    def geometry(self, key: str) -> dict[str, Any] | str:
        """``{"depth", "pose", "dynamic"}`` of frame ``key``, or why it cannot be read (a file
        missing). A damaged file (a pose that is not a rigid transform...) raises, naming it."""
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        frame = self.frames.frames[self.position[key]]
        folder = self.root / MISSIONS[frame.mission]
        files = {f: frame_file(folder, frame.viewpoint, frame.stem, f) for f in GEOMETRY_FIELDS}
        missing = [str(p) for p in files.values() if not p.is_file()]
        if missing:
            found: dict[str, Any] | str = f"missing {missing[0]}"
        else:
            found = {
                "depth": modalities.read_depth(files["depth"]),
                "pose": modalities.read_extrinsics(files["extrinsics"]),
                "dynamic": modalities.read_dynamic_mask(files["dynamic_mask"]),
            }
        with self._lock:
            self._cache[key] = found
            while len(self._cache) > self._size:
                self._cache.popitem(last=False)
        return found


def measure_pair(
    frames: PassFrames,
    key_t: str,
    pred_t: np.ndarray | None,
    gt_t: np.ndarray,
    pred_s: Callable[[str], np.ndarray | str],
    num_classes: int,
    maps: bool = False,
) -> PairResult:
    """Frame ``key_t``'s pair with the next frame of its pass.

    Args:
        frames: the passes.
        key_t: frame t.
        pred_t, gt_t: t's prediction and labels (uint8 [H, W]).
        pred_s: the prediction of a frame by its key, or why there is none.
        num_classes: K.
        maps: also keep t's kept and agreeing pixels (the hardest-images sheet).
    """
    width = pair_columns(num_classes)
    key_s = frames.next_of(key_t)
    if not key_s:
        return PairResult("", PAIR_LAST, "", np.zeros(width, np.int64))
    geometry = [frames.geometry(key_t), frames.geometry(key_s)]
    prediction = pred_s(key_s)
    for found in (*geometry, prediction):
        if isinstance(found, str):
            return PairResult(key_s, PAIR_UNAVAILABLE, found, np.zeros(width, np.int64))
    if np.array_equal(geometry[0]["pose"], geometry[1]["pose"]):
        why = f"{key_t} and {key_s} have identical poses: their consistency would be 1"
        return PairResult(key_s, PAIR_IDENTICAL, why, np.zeros(width, np.int64))
    return cross_view_sums(geometry, pred_t, prediction, gt_t, frames.mask(key_s),
                           num_classes, key_s, maps)  # fmt: skip


def cross_view_sums(
    geometry: list[dict[str, Any]],
    pred_t: np.ndarray,
    pred_s: np.ndarray,
    gt_t: np.ndarray,
    gt_s: np.ndarray,
    num_classes: int,
    key_s: str,
    maps: bool,
) -> PairResult:
    """The pair's row of sums from :func:`claravid.eval.inference.cross_view.cross_view`."""
    from claravid.eval.inference.cross_view import cross_view

    t, s = geometry
    out = cross_view(t["depth"], s["depth"], t["pose"], s["pose"], pred_t, pred_s, gt_t, gt_s,
                     t["dynamic"], s["dynamic"], num_classes)  # fmt: skip
    if out.skipped:
        return PairResult(key_s, PAIR_TURN, "", np.zeros(pair_columns(num_classes), np.int64))
    row = np.concatenate([[out.kept, out.agree, out.agree_gt], out.intersections, out.unions,
                          out.intersections_gt, out.unions_gt]).astype(np.int64)  # fmt: skip
    kept = agree = None
    if maps:
        kept, agree = out.kept_map, out.agree_map
    return PairResult(key_s, PAIR_OK, "", row, kept, agree)

"""Pairs measured as an evaluation goes, and the pairs of lowest consistency kept for its sheet.

:class:`PairStream` takes a model's predictions in dataset order: frame t waits for the next
frame of its pass when that frame is evaluated by the same run (a rank's contiguous shard),
and is measured as soon as its prediction arrives; otherwise (the last frame of the shard or of
a block of the split) the next frame is predicted here, once, so the pair is still counted by
t's run. :class:`PairKeeper` keeps small copies of the k pairs of lowest consistency (their
kept and disagreeing pixels, :func:`claravid.eval.measures.pair_marks.pair_marks`), whose
images are read after the run for ``hardest.png``.
"""

from __future__ import annotations

import heapq
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from claravid.eval.analysis.quality_table import PAIR_OK
from claravid.eval.inference.background import Background
from claravid.eval.inference.hardest import thumbnail
from claravid.eval.inputs.pass_frames import PairResult, PassFrames, measure_pair
from claravid.eval.measures.pair_marks import pair_marks


def pair_consistency(result: PairResult) -> float:
    """The share of a counted pair's kept pixels whose predictions agree (NaN otherwise)."""
    if result.status != PAIR_OK or result.sums[0] <= 0:
        return float("nan")
    return float(result.sums[1] / result.sums[0])


@dataclass
class PairKeeper:
    """The k counted pairs of lowest consistency seen so far, as thumbnails of frame t's
    prediction, labels, kept pixels and agreeing pixels (ties: the lower index). Offers may
    come from several threads."""

    k: int
    heap: list[tuple[float, int, dict[str, Any]]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def offer(self, index: int, key: str, result: PairResult,
              labels: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> None:  # fmt: skip
        """Keep this pair if it is among the k of lowest consistency so far.

        Args:
            index: frame t's index in the evaluation (ties: the lower index is kept).
            key: frame t.
            result: its pair, with both frames' geometry.
            labels: ``(pred_t, gt_t, pred_s, gt_s)``, uint8 [H, W] each.
        """
        value = pair_consistency(result)
        if self.k <= 0 or not np.isfinite(value) or result.geometry is None:
            return
        rank = (-value, -index)  # the root is the most consistent kept pair, evicted first
        with self.lock:
            if len(self.heap) == self.k and rank <= self.heap[0][:2]:
                return
        full_pred_t, full_gt_t, full_pred_s, full_gt_s = labels
        pred_t, gt_t = (thumbnail(np.asarray(a, np.uint8), True) for a in labels[:2])
        t, s = result.geometry
        size = (pred_t.shape[1], pred_t.shape[0])
        kept, agree = pair_marks(t, s, full_pred_t, full_pred_s, full_gt_t, full_gt_s, size)
        item = {"key": key, "next": result.next, "consistency": value, "prediction": pred_t,
                "mask": gt_t, "kept": kept, "agree": agree}  # fmt: skip
        entry = (*rank, item)
        with self.lock:
            if len(self.heap) < self.k:
                heapq.heappush(self.heap, entry)
            elif rank > self.heap[0][:2]:
                heapq.heapreplace(self.heap, entry)


class PairStream:
    """A run's pairs from predictions arriving in dataset order.

    Args:
        frames: the passes of the evaluated frames.
        keys: the keys of the frames this run evaluates, in the order they arrive.
        num_classes: K.
        predict: the prediction (uint8 [H, W]) of a frame this run does not evaluate, by key.
        keeper: where the pairs of lowest consistency go.
        indices: each key's index in the whole evaluation (the keeper's tie-break; default
            the position in ``keys``).
        background: where pairs are measured, beside the model (default: at once).
    """

    def __init__(
        self,
        frames: PassFrames,
        keys: Sequence[str],
        num_classes: int,
        predict: Callable[[str], np.ndarray],
        keeper: PairKeeper | None = None,
        indices: Sequence[int] | None = None,
        background: Background | None = None,
    ) -> None:
        self.frames, self.num_classes, self.predict = frames, num_classes, predict
        self.order = {key: i for i, key in enumerate(keys)}
        self.index = dict(zip(keys, indices if indices is not None else range(len(keys)),
                              strict=True))  # fmt: skip
        self.keeper = keeper
        self.waiting: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        self.background = background or Background(0)
        self.jobs: dict[str, Any] = {}

    def add(self, key: str, pred: np.ndarray, gt: np.ndarray) -> None:
        """Frame ``key``'s prediction and labels (uint8 [H, W])."""
        earlier = self.waiting.pop(key, None)
        if earlier is not None:
            self._measure(*earlier, lambda _key: pred)
        after = self.frames.next_of(key)
        if after and self.order.get(after, -1) > self.order[key]:
            self.waiting[after] = (key, pred, gt)  # measured when the next frame arrives
        else:
            self._measure(key, pred, gt, self.predict)

    def finish(self) -> dict[str, PairResult]:
        """Every frame's pair by key; frames still waiting (their next frame was not reached)
        are measured with the next frame predicted here."""
        for key_t, pred, gt in list(self.waiting.values()):
            self._measure(key_t, pred, gt, self.predict)
        self.waiting.clear()
        return {key: job.result() for key, job in self.jobs.items()}

    def _measure(self, key: str, pred: np.ndarray, gt: np.ndarray,
                 pred_s: Callable[[str], np.ndarray]) -> None:  # fmt: skip
        after = self.frames.next_of(key)
        # Here, not in the thread: it may need the model. Without a next frame measure_pair
        # stops before asking for its prediction.
        other: np.ndarray | str = pred_s(after) if after else ""
        self.jobs[key] = self.background.submit(self._pair, key, pred, gt, after, other)

    def _pair(self, key: str, pred: np.ndarray, gt: np.ndarray, after: str | None,
              other: np.ndarray | str) -> PairResult:  # fmt: skip
        """The pair's sums (in a background thread), offered to the keeper."""
        keeper = self.keeper if self.keeper is not None and self.keeper.k > 0 else None
        result = measure_pair(self.frames, key, pred, gt, lambda _key: other,
                              self.num_classes, keep_geometry=keeper is not None)  # fmt: skip
        # A pair with geometry was measured, so the next frame had a prediction.
        if keeper is not None and result.geometry is not None and isinstance(other, np.ndarray):
            assert after is not None  # a measured pair has a next frame
            labels = (pred, gt, other, self.frames.mask(after))
            keeper.offer(self.index[key], key, result, labels)
        result.geometry = None  # full-size depth maps are not kept past the sheet
        return result

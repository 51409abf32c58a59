"""The hardest-images sheet's pair marks: which of frame t's pixels agree with frame s."""

from __future__ import annotations

import numpy as np

from claravid.eval.analysis.quality_table import PAIR_OK
from claravid.eval.inference.pair_stream import PairKeeper
from claravid.eval.inputs.pairs import FrameGeometry
from claravid.eval.inputs.pass_frames import PairResult
from claravid.io.layout import DYNAMIC_MASK_STATIC


def _frame(height: int, width: int) -> FrameGeometry:
    """Flat ground 12 m away, every pixel static, a pinhole camera at the world origin."""
    intrinsics = np.array([[7.0, 0.0, width / 2], [0.0, 7.0, height / 2], [0.0, 0.0, 1.0]])
    return FrameGeometry(
        depth=np.full((height, width), 12.0, np.float32),
        c2w=np.eye(4),
        dynamic=np.full((height, width), DYNAMIC_MASK_STATIC, np.uint8),
        intrinsics=intrinsics,
    )


def test_marks_compare_the_two_predictions_not_a_prediction_with_labels() -> None:
    # Both frames see the same ground (same pose): each pixel of t lands on itself in s. The
    # predictions agree everywhere; the labels (another class) agree with neither prediction.
    h, w = 6, 10
    pred = np.full((h, w), 1, np.uint8)
    gt = np.full((h, w), 2, np.uint8)
    keeper = PairKeeper(k=1)
    sums = np.zeros(8, np.int64)
    sums[:2] = (h * w, h * w // 2)  # consistency 0.5: a pair worth keeping
    result = PairResult("s", PAIR_OK, "", sums, (_frame(h, w), _frame(h, w)))
    keeper.offer(0, "t", result, (pred, gt, pred.copy(), gt.copy()))
    (item,) = [entry[2] for entry in keeper.heap]
    assert item["kept"].shape == (h, w)
    assert item["kept"].all()  # hits, static and labelled in both frames
    assert item["agree"].all()  # pred_t == pred_s at every kept pixel
    # One column of s predicted otherwise: exactly that column of t disagrees.
    other = pred.copy()
    other[:, 3] = 4
    keeper = PairKeeper(k=1)
    keeper.offer(0, "t", result, (pred, gt, other, gt.copy()))
    agree = keeper.heap[0][2]["agree"]
    expected = np.ones((h, w), bool)
    expected[:, 3] = False
    np.testing.assert_array_equal(agree, expected)

"""A training run records the ground sampling distance of its training frames."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

FOCAL = 2627.3023516478706  # fx at 4032 px wide (the dataset's intrinsics)


def _depth_metres(path):
    """The depth PNG decoded from its definition: (R + 256 G + 65536 B) / (2^24 - 1) x 1000."""
    b, g, r = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float64).transpose(2, 0, 1)
    return (r + 256 * g + 65536 * b) / (2**24 - 1) * 1000


def test_the_checkpoint_holds_the_median_centre_gsd_of_the_training_frames(trained_v2):
    from claravid.io.layout import MISSIONS, frame_file
    from claravid.train.data import build_train_dataset

    record = torch.load(trained_v2["ckpt"], weights_only=True)["gsd"]
    frames = build_train_dataset(trained_v2["cfg"]).frames
    root = Path(trained_v2["cfg"].data.root)
    values = []
    for f in frames:  # 64 x 48 frames: the 4 pixels at the centre are rows 23-24, columns 31-32
        depth = _depth_metres(frame_file(root / MISSIONS[f.mission], f.viewpoint, f.stem, "depth"))
        values.append(depth[23:25, 31:33].mean() / (FOCAL * 64 / 4032))
    assert record["frames"] == len(values) > 3
    assert record["metres_per_pixel"] == pytest.approx(np.median(values), rel=1e-5)
    assert len(set(np.round(values, 6))) > 1  # frames of several altitudes: the median chooses


def test_a_stated_gsd_wins(claravid_root, tmp_path):
    from claravid.train import load_config
    from claravid.train.data import build_train_dataset
    from claravid.train.loop import training_gsd
    from tests.tiny import tiny

    cfg = load_config("demo", tiny(claravid_root, tmp_path / "run", "data.gsd=0.031"))
    assert training_gsd(cfg, build_train_dataset(cfg)) == {
        "metres_per_pixel": 0.031,
        "source": "data.gsd",
    }
    with pytest.raises(ValueError, match=r"data\.gsd"):
        load_config("demo", tiny(claravid_root, tmp_path / "run", "data.gsd=-1"))

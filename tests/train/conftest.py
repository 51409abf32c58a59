"""Training tests: the tiny generated ClaraVid tree, a tiny UAVid tree, tiny models."""

import numpy as np
import pytest
import torch

from claravid.data.palettes import load_palette
from claravid.io import modalities


@pytest.fixture(scope="session")
def uavid_root(tmp_path_factory):
    """uavid_{train,val}/seq1 with 3 frames of 64×48 each, colour labels in blocks."""
    root = tmp_path_factory.mktemp("uavid")
    colors = load_palette("uavid").colors
    rng = np.random.default_rng(0)
    for split in ("train", "val"):
        for frame in range(3):
            ids = np.repeat(np.repeat(rng.integers(0, 8, (6, 8)), 8, 0), 8, 1)
            image = (colors[ids] * 0.8 + rng.integers(0, 50, (48, 64, 3))).astype(np.uint8)
            base = root / f"uavid_{split}" / "seq1"
            modalities._write_image(base / "Images" / f"{frame:06d}.png", image)
            modalities.write_seg_color(base / "Labels" / f"{frame:06d}.png", colors[ids])
    return root


@pytest.fixture(autouse=True)
def _one_thread():
    """One intra-op thread: these models are so small that a second thread only adds overhead
    (3× slower on a busy 2-core machine)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)

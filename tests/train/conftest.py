"""Training tests: the tiny generated ClaraVid tree, a tiny UAVid tree, tiny models."""

import numpy as np
import pytest
import torch

from claravid.data.palettes import load_palette
from claravid.io import modalities

# A tiny random-init backbone (of the config's architecture) and head, 28² crops, the fixture's
# 5 test frames as val set (26/5/5 with 150 m blocks), CPU, one thread, no workers, no progress
# bar.
TINY = [
    "model.weights=null",
    "model.backbone_kwargs.embed_dim=32",
    "model.backbone_kwargs.depth=4",
    "model.backbone_kwargs.num_heads=2",
    "model.layers=[0,1,2,3]",
    "model.features=8",
    "model.out_channels=[8,8,8,8]",
    "data.augment.crop_height=28",
    "data.augment.crop_width=28",
    "data.num_workers=0",
    "data.val_split=test",
    "train.batch_size=4",
    "train.warmup_steps=0",
    "train.device=cpu",
    "train.threads=1",
    "val.window=28",
    "val.scale=1.0",
    "val.batch_size=8",
    "log.progress=false",
]


#: Per head: the head named, and what TINY sets that the head does not take cleared (the linear
#: head then reads the last block).
HEAD_OVERRIDES = {
    "dpt": [],
    "linear": ["model.head=linear", "model.layers=null", "model.features=null",
               "model.out_channels=null"],
    "upernet": ["model.head=upernet", "model.out_channels=null"],
}  # fmt: skip


def tiny(root, out, *extra):
    """Overrides for a tiny run on ``root`` writing to ``out``."""
    return [*TINY, f"data.root={root}", f"out_dir={out}", *extra]


def tiny_v3(root, out, *extra, backbone="dinov3_vits16"):
    """``tiny`` with a tiny random-init DINOv3 backbone (the same widths and depth): patches of
    16, so 32² crops and windows (two patches a side; 28 is not a multiple of 16)."""
    sizes = ["data.augment.crop_height=32", "data.augment.crop_width=32", "val.window=32"]
    return tiny(root, out, f"model.backbone={backbone}", *sizes, *extra)


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


def miou_by_hand(checkpoint, cfg):
    """The val mIoU of a checkpoint, counted here with numpy from its predictions.

    Each val frame is predicted with the run's validation windows (``claravid.eval``'s public
    ``predict_labels``); then, over all frames, per class: pixels labelled and predicted that
    class over pixels labelled or predicted that class (pixels labelled 255 left out),
    averaged over the classes that occur in either (docs/report-format.md, "Conventions").
    """
    from claravid import models
    from claravid.eval import WindowConfig, predict_labels
    from claravid.train.data import build_val_dataset

    model = models.load_checkpoint(checkpoint).eval()
    v, a = cfg.val, cfg.data.augment
    window = WindowConfig(v.window, v.stride, v.scale, v.batch_size, "fp32",
                          mean=tuple(a.mean), std=tuple(a.std))  # fmt: skip
    k = model.num_classes
    hits, predicted, labelled = np.zeros(k), np.zeros(k), np.zeros(k)
    dataset = build_val_dataset(cfg)
    with torch.no_grad():
        for i in range(len(dataset)):
            sample = dataset[i]
            truth = sample["mask"].numpy().astype(np.int64)
            guess = predict_labels(model, sample["image"], window).numpy()
            valid = truth != 255
            truth, guess = truth[valid], guess[valid]
            hits += np.bincount(truth[truth == guess], minlength=k)
            predicted += np.bincount(guess, minlength=k)
            labelled += np.bincount(truth, minlength=k)
    union = predicted + labelled - hits
    return float(np.mean(hits[union > 0] / union[union > 0]))

"""The tiny architectures and training overrides every test builds, declared once.

Real architectures with real code paths, only narrow and shallow: a forward pass takes
milliseconds, an ONNX export seconds. A test that needs another size says why beside it.
"""

from __future__ import annotations

from pathlib import Path

#: A ViT of 4 blocks, width 32, 2 heads: the trunk of every tiny segmenter (4 blocks: the DPT
#: head taps 4 of them).
VIT = {"embed_dim": 32, "depth": 4, "num_heads": 2}
#: `VIT` with a positional table for 56 px, a 4x4 patch grid at patch 14: inputs of 56 need no
#: interpolation, every other size does (the offset bicubic is exercised both ways).
VIT_56 = {**VIT, "img_size": 56}
#: 3 blocks at the 4x4 grid: the backbone alone against the official DINOv2 code.
VIT_3 = {**VIT_56, "depth": 3}
#: 2 blocks at a 2x2 grid: the weights tests, which build whole official state dicts.
VIT_2 = {"embed_dim": 32, "depth": 2, "num_heads": 2, "img_size": 28}
#: DINOv3 against transformers: head width 16, so 4 RoPE periods.
TINY_V3 = {"embed_dim": 64, "depth": 3, "num_heads": 4}

#: A DPT head on all 4 blocks, 8 channels everywhere (evaluation and training tests).
HEAD = {"layers": [0, 1, 2, 3], "features": 8, "out_channels": [8, 8, 8, 8]}
#: A DPT head whose reassemble widths differ per level (a swapped level shows as a shape error).
WIDE_HEAD = {"layers": [0, 1, 2, 3], "features": 16, "out_channels": [8, 16, 32, 32]}
#: `build_model` keyword arguments of the evaluation tests' segmenter.
MODEL = {"backbone_kwargs": VIT, **HEAD}

#: Width x height: the 48 (high) x 64 (wide) fixture frames take 4 overlapping 42x56 windows.
WINDOW = "56x42"

# A tiny random-init backbone (of the config's architecture) and head, 28² crops, the fixture's
# 5 test frames as val set (26/5/5 with 150 m blocks), CPU, one thread, no workers, no progress
# bar.
OVERRIDES = [
    "model.weights=null",
    f"model.backbone_kwargs.embed_dim={VIT['embed_dim']}",
    f"model.backbone_kwargs.depth={VIT['depth']}",
    f"model.backbone_kwargs.num_heads={VIT['num_heads']}",
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


def tiny(root: str | Path, out: str | Path, *extra: str) -> list[str]:
    """Overrides for a tiny run on ``root`` writing to ``out``."""
    return [*OVERRIDES, f"data.root={root}", f"out_dir={out}", *extra]


def tiny_v3(root: str | Path, out: str | Path, *extra: str, backbone="dinov3_vits16") -> list[str]:
    """``tiny`` with a tiny random-init DINOv3 backbone (the same widths and depth): patches of
    16, so 32² crops and windows (two patches a side; 28 is not a multiple of 16)."""
    sizes = ["data.augment.crop_height=32", "data.augment.crop_width=32", "val.window=32"]
    return tiny(root, out, f"model.backbone={backbone}", *sizes, *extra)


def tiny_model(num_classes: int = 8, seed: int = 0, backbone: str = "dinov2_vits14"):
    """The evaluation tests' segmenter (`MODEL`), seeded, in eval mode."""
    import torch

    from claravid import models

    torch.manual_seed(seed)
    return models.build_model(backbone, num_classes, **MODEL).eval()


#: Per head: the head named, and what `OVERRIDES` sets that the head does not take cleared (the
#: linear head then reads the last block).
HEAD_OVERRIDES = {
    "dpt": [],
    "linear": ["model.head=linear", "model.layers=null", "model.features=null",
               "model.out_channels=null"],
    "upernet": ["model.head=upernet", "model.out_channels=null"],
}  # fmt: skip

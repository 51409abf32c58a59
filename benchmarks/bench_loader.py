"""Loader throughput: ClaraVidSegmentation + training transforms vs the SDK's naive way.

Run: ``.venv/bin/python benchmarks/bench_loader.py [--frames 6] [--samples 24]``

On full-size 4032×3024 frames made by the generator, measures samples/s of
  - baseline: the official SDK's way (PIL-decode the RGB and the panoptic PNG into the
    SDK's int32 pair, remap the full label image, then crop), then the same augmentations;
  - ours, first epoch: OpenCV decoding, class channel only, table remap, crop-first augs;
  - ours, label cache warm: the same with labels from the single-channel cache;
and DataLoader scaling with 1 and 2 workers. Prints each ratio against the baseline.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")

import numpy as np
import torch
from PIL import Image
from torch.utils.data import DataLoader, RandomSampler

from claravid.palettes import load_palette
from claravid.segmentation import ClaraVidSegmentation
from claravid.synth import synthesize
from claravid.transforms import train_transforms


class NaiveSDKDataset(torch.utils.data.Dataset):
    """The official SDK's reading path, then remap the full image, then crop + augment."""

    def __init__(self, frames, palette, transforms) -> None:
        self.frames, self.palette, self.transforms = frames, palette, transforms
        self.lut = palette.lut.astype(np.int64)  # static label codes are the class ids

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> dict:
        frame = self.frames[index]
        rgb = np.array(Image.open(frame.paths["rgb"]).convert("RGB"))
        pan = np.array(Image.open(frame.paths["pan_seg"]).convert("RGB")).astype(np.int32)
        pan_seg = np.zeros((*pan.shape[:2], 2), dtype=np.int32)
        pan_seg[..., 0] = pan[..., 2] * 256 + pan[..., 1]
        pan_seg[..., 1] = pan[..., 0]
        mask = self.lut[pan_seg[..., 1]]  # remap the full image
        sample = {
            "image": torch.from_numpy(rgb).permute(2, 0, 1),
            "mask": torch.from_numpy(mask.astype(np.uint8)),
        }
        return self.transforms(sample)


def throughput(dataset, samples: int) -> float:
    start = time.perf_counter()
    for i in range(samples):
        dataset[i % len(dataset)]
    return samples / (time.perf_counter() - start)


def loader_throughput(dataset, workers: int, samples: int) -> float:
    """Steady-state samples/s: one long shuffled epoch, timed after the first batches."""
    warmup = 2 * workers
    sampler = RandomSampler(dataset, replacement=True, num_samples=samples + warmup)
    loader = DataLoader(dataset, batch_size=1, sampler=sampler, num_workers=workers)
    batches = iter(loader)
    for _ in range(warmup):  # worker start-up is not the steady state
        next(batches)
    start = time.perf_counter()
    for _ in batches:
        pass
    return samples / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=6, help="4032×3024 frames to generate")
    parser.add_argument("--samples", type=int, default=24, help="samples timed per variant")
    args = parser.parse_args()
    torch.set_num_threads(1)  # one sample at a time per process, like a DataLoader worker

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "claravid"
        start = time.perf_counter()
        synthesize(root, seed=0, frames_per_viewpoint=args.frames, size=(4032, 3024),
                   missions=["urban_1"], altitude=["low"], direction=["h"])  # fmt: skip
        print(f"generated {args.frames} frames of 4032×3024 in {time.perf_counter() - start:.1f} s")
        transforms = train_transforms()
        palette = load_palette("claravid")
        ours = ClaraVidSegmentation(root, split="all", transforms=transforms)
        cached = ClaraVidSegmentation(
            root, split="all", transforms=transforms, label_cache=Path(tmp) / "cache"
        )
        for i in range(len(cached)):
            cached.read_mask(i)  # prepare the cache once
        naive = NaiveSDKDataset(ours.frames, palette, transforms)

        throughput(naive, 2)  # warm-up: imports, allocator
        base = throughput(naive, args.samples)
        first = throughput(ours, args.samples)
        warm = throughput(cached, args.samples)
        print(f"\n{'variant':<44}{'samples/s':>10}{'× baseline':>12}")
        print(f"{'baseline (SDK way: PIL, remap full, crop)':<44}{base:>10.2f}{1.0:>12.2f}")
        print(f"{'ours, first epoch (no label cache)':<44}{first:>10.2f}{first / base:>12.2f}")
        print(f"{'ours, label cache warm':<44}{warm:>10.2f}{warm / base:>12.2f}")

        print("\nDataLoader (batch 1, label cache warm):")
        for workers in (1, 2):
            rate = loader_throughput(cached, workers, args.samples)
            naive_rate = loader_throughput(naive, workers, args.samples)
            print(
                f"  {workers} worker(s): ours {rate:.2f}/s, baseline {naive_rate:.2f}/s, "
                f"× {rate / naive_rate:.2f} ({rate / workers:.2f}/s per worker)"
            )


if __name__ == "__main__":
    main()

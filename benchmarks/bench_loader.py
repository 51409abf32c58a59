"""The data path at ClaraVid's real size against what the hardware can do.

Run: ``.venv/bin/python benchmarks/bench_loader.py [--frames 6] [--samples 24]``

On generated 4032×3024 frames (``uavid`` palette, default augmentations), one core
(``torch.set_num_threads(1)``, ``cv2.setNumThreads(1)``), every figure against a baseline
measured in the same run:

1. Baseline: ``cv2.imread`` of the whole RGB frame (full colour decode), frames/s.
2. Label cache preparation (what ``claravid-cache`` does), against decoding every panoptic PNG
   once (``cv2.imread``; target ≤ 1.3×) and against decoding every label file the palette
   reads (the panoptic PNG and, for ``uavid``, the dynamic mask).
3. Training sample (crop window drawn from the headers, the RGB window and the label window
   read alone, then the augmentations), first epoch (cache just prepared) and warm, samples/s.
   Target ≥ 2× the baseline's frames/s. Also ``claravid-train``'s crop (the same, uint8: it is
   normalised on the model's device) and, for reference, the former path: a full decode of the
   RGB and of the labels, then the crop.
4. Evaluation sample (``claravid-eval``'s: the whole frame as uint8 and its labels from the
   cache), time per sample. Target ≤ 1.5× the baseline's time per frame. Also the documented
   one, ``ClaraVidSegmentation(..., transforms=eval_transforms())`` (the exact uint8 frame and
   a uint8 mask), same target, and for reference what it cost before: a float32 frame
   normalised on the CPU and an int64 mask (``eval_transforms(normalize=True)``, int64 mask).
5. DataLoader over ``claravid-train``'s crops, 1 and 2 worker processes. Target ≥ 1.8× on 2
   cores. Beside it, what this machine's 2 cores give at all: the same crops made in 2
   processes at once (no DataLoader) against 1 (a shared VM's second core may give less than
   a whole core's work).
6. What a 16-core node gives (16 × the one-core rate) next to what one H100 consumes training
   the DPT head on a frozen ViT-L/14 at 630² (``bench_train``'s model-only figure where a GPU
   ran; else an estimate from the FLOPs counted here on the meta device at 40 % of the H100's
   dense bf16 peak).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")

import cv2
import torch
import torch.multiprocessing as mp
from torch.utils.data import DataLoader

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import augment_config, eval_transforms, train_transforms
from claravid.io import jpeg_region
from claravid.synth import synthesize
from claravid.train.data import CropDataset, collate_crops

H100_BF16_DENSE = 989e12  # FLOP/s, SXM, dense (no sparsity)
MFU = 0.40  # a typical achieved share of the peak for a ViT training step


def per_item(fn, items, repeats: int = 1) -> float:
    """Median seconds of ``fn(item)`` over the items (each timed ``repeats`` times)."""
    times = []
    for _ in range(repeats):
        for item in items:
            start = time.perf_counter()
            fn(item)
            times.append(time.perf_counter() - start)
    return statistics.median(times)


class FormerPath(torch.utils.data.Dataset):
    """What a training sample cost before: the whole RGB and the whole label image decoded,
    then the crop and the augmentations (the transform cuts the crop from the full frame)."""

    def __init__(self, base: ClaraVidSegmentation, transforms) -> None:
        self.base, self.transforms = base, transforms  # base: no transforms, whole frames

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index: int) -> dict:
        full = self.base[index]
        return self.transforms({"image": full["image"], "mask": full["mask"]})


def crop_items(crops: CropDataset, count: int, offset: int = 0) -> list[tuple[int, int]]:
    """``count`` (frame, seed) items, what ``claravid-train``'s sampler hands its loader."""
    return [((offset + i) % len(crops), offset + i) for i in range(count)]


def loader_rate(crops: CropDataset, workers: int, samples: int) -> float:
    """Steady-state crops/s of a DataLoader (worker start-up not timed)."""
    warmup = 2 * max(1, workers)
    items = crop_items(crops, samples + warmup)
    batches = iter(DataLoader(crops, batch_size=1, sampler=items, num_workers=workers,
                              collate_fn=collate_crops))  # fmt: skip
    for _ in range(warmup):
        next(batches)
    start = time.perf_counter()
    for _ in batches:
        pass
    return samples / (time.perf_counter() - start)


def _make_crops(crops: CropDataset, items: list, barrier, out) -> None:
    barrier.wait()
    start = time.perf_counter()
    for item in items:
        crops[item]
    out.put(time.perf_counter() - start)


def process_rate(crops: CropDataset, processes: int, samples: int) -> float:
    """Crops/s of ``processes`` processes each making ``samples`` crops at once (fork)."""
    context = mp.get_context("fork")
    barrier, out = context.Barrier(processes), context.Queue()
    jobs = [
        context.Process(target=_make_crops, args=(crops, items, barrier, out))
        for items in (crop_items(crops, samples, p * samples) for p in range(processes))
    ]
    for job in jobs:
        job.start()
    seconds = max(out.get() for _ in jobs)
    for job in jobs:
        job.join()
    return processes * samples / seconds


def step_flops(crop: int = 630) -> float:
    """FLOPs of one training step of one image: frozen ViT-L/14 forward + DPT head forward and
    backward, counted by PyTorch on the meta device (nothing is computed)."""
    from torch.utils.flop_counter import FlopCounterMode

    from claravid.models import build_model

    with torch.device("meta"):
        model = build_model("dinov2_vitl14", num_classes=8)
        image = torch.empty(1, 3, crop, crop)
    counter = FlopCounterMode(display=False)
    with counter:
        model(image).sum().backward()  # the frozen backbone has no backward
    return float(counter.get_total_flops())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=6, help="4032×3024 frames to generate")
    parser.add_argument("--samples", type=int, default=24, help="samples timed per variant")
    parser.add_argument(
        "--eval-only", action="store_true", help="the baseline and the evaluation samples only"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)

    with tempfile.TemporaryDirectory() as tmp:
        root, cache = Path(tmp) / "claravid", Path(tmp) / "cache"
        start = time.perf_counter()
        synthesize(root, seed=0, frames_per_viewpoint=args.frames, size=(4032, 3024),
                   missions=["urban_1"], altitude=["low"], direction=["h"])  # fmt: skip
        print(f"generated {args.frames} frames of 4032×3024 in {time.perf_counter() - start:.0f} s")
        print(f"RGB crops: {jpeg_region.decoder()}\n")
        transforms = train_transforms()
        train = ClaraVidSegmentation(root, split="all", palette="uavid", transforms=transforms,
                                     label_cache=cache)  # fmt: skip
        frames = train.frames
        rgb = [str(f.paths["rgb"]) for f in frames]
        pan = [str(f.paths["pan_seg"]) for f in frames]

        decode = per_item(lambda p: cv2.imread(p, cv2.IMREAD_COLOR), rgb, repeats=2)
        print(f"1. baseline cv2.imread, whole RGB frame: {decode * 1e3:6.1f} ms "
              f"({1 / decode:.2f} frames/s)")  # fmt: skip

        png = sum(per_item(lambda p: cv2.imread(p, cv2.IMREAD_COLOR), [p]) for p in pan)
        dyn = [str(f.paths["dynamic_mask"]) for f in frames]  # the uavid palette reads them too
        grey = sum(per_item(lambda p: cv2.imread(p, cv2.IMREAD_UNCHANGED), [p]) for p in dyn)
        summary = train.prepare_label_cache()
        print(f"2. label cache preparation: {summary.seconds / len(frames) * 1e3:6.1f} ms/frame, "
              f"× {summary.seconds / png:.2f} the panoptic PNG decodes (target ≤ 1.3), "
              f"× {summary.seconds / (png + grey):.2f} the decodes of every label file the "
              f"palette reads (panoptic + dynamic mask); {summary.bytes_per_frame / 1e3:.0f} "
              f"kB/frame, {summary.bytes_total / 1e6:.1f} MB in all")  # fmt: skip

        n = args.samples
        if not args.eval_only:
            training_samples(args, root, cache, train, transforms, decode)
        evaluation_samples(root, cache, rgb, decode)
        if not args.eval_only:
            scaling(root, cache, n, train)


def training_samples(args, root, cache, train, transforms, decode) -> None:
    """3. A training sample, first epoch and warm, ``claravid-train``'s crop, the former path."""
    n = args.samples
    frames = train.frames
    indices = [i % len(train) for i in range(n)]
    first = per_item(train.__getitem__, indices[: len(train)])  # each entry read once
    warm = per_item(train.__getitem__, indices)
    whole = ClaraVidSegmentation(root, split="all", palette="uavid", label_cache=cache)
    crops = CropDataset(whole, augment_config(None))
    assert crops.by_window == (jpeg_region.decoder() == jpeg_region.REGION_DECODE)
    uint8 = per_item(crops.__getitem__, crop_items(crops, n))
    former = per_item(FormerPath(whole, transforms).__getitem__, indices[: len(frames)])
    print("3. training sample (uavid, default augmentations):")
    for name, seconds in (("first epoch (cache prepared)", first), ("label cache warm", warm),
                          ("claravid-train's crop (uint8)", uint8),
                          ("former path (whole frames)", former)):  # fmt: skip
        print(
            f"   {name:<30} {seconds * 1e3:6.1f} ms  {1 / seconds:6.2f} samples/s  "
            f"× {decode / seconds:.2f} the baseline rate (target ≥ 2)"
        )


def evaluation_samples(root, cache, rgb, decode) -> None:
    """4. What an evaluation sample costs: claravid-eval's and the documented dataset's."""
    from claravid.eval.inputs.datasets import open_data

    os.environ["CLARAVID_CACHE"] = str(cache.parent / "eval-cache")
    data = open_data(root, split="all", palette="uavid")
    data.dataset[0]  # the cache entry of this palette's key
    for i in range(len(data)):
        data.read_mask(i)
    evaluation = per_item(data.dataset.__getitem__, range(len(data)), repeats=2)
    print(f"4. evaluation sample (uint8 frame + labels): {evaluation * 1e3:6.1f} ms, "
          f"× {evaluation / decode:.2f} the baseline time (target ≤ 1.5)")  # fmt: skip
    documented = ClaraVidSegmentation(root, split="all", palette="uavid", label_cache=cache,
                                      transforms=eval_transforms())  # fmt: skip
    former_eval = ClaraVidSegmentation(root, split="all", palette="uavid", label_cache=cache,
                                       transforms=eval_transforms(normalize=True),
                                       mask_dtype=torch.int64)  # fmt: skip
    sample = documented[0]
    assert sample["image"].dtype == torch.uint8 and sample["mask"].dtype == torch.uint8
    for name, ds in (("eval_transforms() (uint8 frame, uint8 mask)", documented),
                     ("former: float32 frame, int64 mask", former_eval)):  # fmt: skip
        seconds = per_item(ds.__getitem__, range(len(ds)), repeats=2)
        print(f"   ClaraVidSegmentation + {name:<45} {seconds * 1e3:6.1f} ms, "
              f"× {seconds / decode:.2f} the baseline time (target ≤ 1.5)")  # fmt: skip
    half = per_item(lambda p: cv2.imread(p, cv2.IMREAD_REDUCED_COLOR_2), rgb, repeats=2)
    print(
        f"   for --scale 0.5: the decoder's own 2× scaling {half * 1e3:6.1f} ms, "
        f"× {half / decode:.2f} the full decode (not offered: see docs/evaluation.md)"
    )


def scaling(root, cache, n, train) -> None:
    """5. The DataLoader over 1 and 2 workers; 6. a 16-core node against one H100."""
    whole = ClaraVidSegmentation(root, split="all", palette="uavid", label_cache=cache)
    crops = CropDataset(whole, augment_config(None))
    indices = [i % len(train) for i in range(n)]
    warm = per_item(train.__getitem__, indices)
    loader_n = max(4 * n, 96)  # long enough that start-up and the last batches do not count
    one = loader_rate(crops, 1, loader_n)
    two = loader_rate(crops, 2, loader_n)
    ceiling = process_rate(crops, 2, loader_n // 2) / process_rate(crops, 1, loader_n // 2)
    print(
        f"5. DataLoader of claravid-train's crops: 1 worker {one:.2f}/s, 2 workers "
        f"{two:.2f}/s: × {two / one:.2f} (target ≥ 1.8 on 2 cores; {os.cpu_count()} cores "
        f"here, where 2 processes making crops without a DataLoader give × {ceiling:.2f})"
    )

    flops = step_flops()
    gpu = H100_BF16_DENSE * MFU / flops
    print(
        f"6. a 16-core node: {16 / warm:.0f} samples/s (16 × the one-core rate); one H100 "
        f"consumes ~{gpu:.0f} crops/s (estimate: {flops / 1e12:.2f} TFLOP per crop and "
        f"step, {MFU:.0%} of {H100_BF16_DENSE / 1e12:.0f} TFLOP/s bf16; no GPU here)"
    )


if __name__ == "__main__":
    main()

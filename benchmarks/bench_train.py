"""Training throughput: the optimisation step and the loader side by side, and which one limits.

Run: ``.venv/bin/python benchmarks/bench_train.py [--frames-per-viewpoint 1] [--workers 0 2]``

1. Loader: the training loader (``claravid.train.data.build_train_loader``: decode a full 4032×3024
   frame, k random 630² crops with the training augmentations) on generated full-size frames,
   images/s for each number of workers and ``crops_per_frame`` k. Baseline: k = 1 (the paper).
2. Step: forward + backward + AdamW of the segmenter on CPU (``--cpu-backbone``, default a
   ViT-S/14 at 224², fp32), images/s; it prints which side is the bottleneck.
3. GPU (skipped without CUDA): ``dinov2_vitl14`` frozen + DPT head at 630², batch 16,
   bf16 vs fp32, torch.compile off/on; images/s of the step, and how many loader workers at
   which k would keep up (from the per-worker rate measured in 1).
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")

import torch
import torch.nn.functional as F

from claravid import models
from claravid.synth import synthesize
from claravid.train.config import load_config
from claravid.train.data import build_train_dataset, build_train_loader
from claravid.train.optim import build_optimizer


def loader_rate(root: Path, workers: int, k: int, batch: int, batches: int) -> float:
    """Images/s of the training loader in steady state (first batches not timed)."""
    cfg = load_config(
        "claravid_dpt_vitl14",
        [f"data.root={root}", "out_dir=/tmp/unused", f"data.num_workers={workers}",
         f"data.crops_per_frame={k}", f"train.batch_size={batch}", "data.train_split=all"],
    )  # fmt: skip
    loader = build_train_loader(build_train_dataset(cfg), cfg)
    it = iter(loader)
    for _ in range(2 if workers else 1):
        next(it)
    start = time.perf_counter()
    n = sum(next(it)["image"].shape[0] for _ in range(batches))
    rate = n / (time.perf_counter() - start)
    del it
    return rate


def step_rate(backbone: str, size: int, batch: int, reps: int, device: str, amp: str,
              compile_: bool, kwargs: dict | None = None) -> float:  # fmt: skip
    """Images/s of one training step (frozen backbone, DPT head, AdamW), after warm-up."""
    model = models.build_model(backbone, 19, backbone_kwargs=kwargs).to(device)
    cfg = load_config("claravid_dpt_vitl14", ["data.root=/x", "out_dir=/x"])
    opt = build_optimizer(model, cfg)
    fwd = torch.compile(model) if compile_ else model
    dtype = {"bf16": torch.bfloat16, "fp16": torch.float16}.get(amp)
    x = torch.randn(batch, 3, size, size, device=device)
    y = torch.randint(0, 19, (batch, size, size), device=device)

    def step() -> None:
        with torch.autocast(device, dtype=dtype, enabled=dtype is not None):
            logits = fwd(x)
        loss = F.cross_entropy(logits.float(), y, ignore_index=255)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.head.parameters(), 1.0)
        opt.step()

    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    for _ in range(3 if compile_ else 1):
        step()
    sync()
    start = time.perf_counter()
    for _ in range(reps):
        step()
    sync()
    return batch * reps / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames-per-viewpoint", type=int, default=1, help="full-size frames")
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--crops", type=int, nargs="+", default=[1, 2, 4], help="values of k")
    parser.add_argument("--batches", type=int, default=4, help="timed loader batches of 8")
    parser.add_argument("--cpu-backbone", default="dinov2_vits14")
    parser.add_argument("--cpu-size", type=int, default=224)
    parser.add_argument("--cpu-batch", type=int, default=8)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--gpu-batch", type=int, default=16)
    parser.add_argument("--gpu-reps", type=int, default=20)
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "claravid"
        os.environ["CLARAVID_CACHE"] = str(Path(tmp) / "cache")
        t0 = time.perf_counter()
        synthesize(root, seed=0, frames_per_viewpoint=args.frames_per_viewpoint,
                   size=(4032, 3024), missions=["urban_1"], progress=False)  # fmt: skip
        print(f"generated full-size 4032×3024 frames in {time.perf_counter() - t0:.0f} s\n")
        print("loader: decode a full frame, k random 630² crops + augmentations (images/s)")
        print(f"  {'workers':>7} {'k':>3} {'images/s':>9} {'vs k=1':>7}")
        rates: dict[tuple[int, int], float] = {}
        for workers, k in itertools.product(args.workers, args.crops):
            rates[workers, k] = loader_rate(root, workers, k, 8, args.batches)
            base = rates[workers, args.crops[0]]
            print(
                f"  {workers:>7} {k:>3} {rates[workers, k]:>9.1f} {rates[workers, k] / base:>6.2f}×"
            )
        per_worker = {k: rates[0, k] for k in args.crops} if 0 in args.workers else {}

    torch.set_num_threads(os.cpu_count() or 1)
    cpu = step_rate(args.cpu_backbone, args.cpu_size, args.cpu_batch, args.reps, "cpu",
                    "fp32", False)  # fmt: skip
    print(f"\nstep on CPU: {args.cpu_backbone} frozen + DPT head at {args.cpu_size}², batch "
          f"{args.cpu_batch}, fp32: {cpu:.1f} images/s")  # fmt: skip
    best_loader = max(rates.values())
    side = "the loader" if best_loader < cpu else "the training step"
    print(f"bottleneck on this machine: {side} (best loader {best_loader:.1f} vs step "
          f"{cpu:.1f} images/s)")  # fmt: skip

    if not torch.cuda.is_available():
        print("\nGPU section skipped: no CUDA device (vitl14 at 630², batch 16, bf16 vs fp32, "
              "torch.compile on/off)")  # fmt: skip
        return 0
    name = torch.cuda.get_device_name()
    print(f"\nGPU ({name}): dinov2_vitl14 frozen + DPT head, 630², batch {args.gpu_batch}")
    results = {}
    for amp, compile_ in itertools.product(("fp32", "bf16"), (False, True)):
        rate = step_rate("dinov2_vitl14", 630, args.gpu_batch, args.gpu_reps, "cuda", amp, compile_)
        results[amp, compile_] = rate
        print(f"  {amp:>4} compile={'on ' if compile_ else 'off'} {rate:8.1f} images/s "
              f"({rate / results['fp32', False]:.2f}× fp32 eager)")  # fmt: skip
    best = max(results.values())
    for k, rate in per_worker.items():
        print(f"  to feed {best:.0f} images/s with k={k}: ~{best / rate:.0f} loader workers "
              f"(one worker gives {rate:.1f} images/s)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What each segmentation head costs on top of the frozen backbone: DPT (the baseline), linear,
UperNet, on the features a backbone gives at its natural size.

    PYTHONPATH=. python benchmarks/bench_heads.py                     # ViT-L/16 at 640², CPU
    PYTHONPATH=. python benchmarks/bench_heads.py --backbone dinov2_vitl14 --reps 5
    PYTHONPATH=. python benchmarks/bench_heads.py --device cuda --batch 16 --amp bf16

The backbone runs once, outside the timings (its features are the same for every head: it is
frozen, and its cost does not depend on the head); each head then gets those four taps (the
linear head the last one). Timed, alternating the heads (A B C A B C) in one run: inference
(eval mode, batch 1, no gradients) and a training step (train mode, ``--batch`` crops, forward,
cross-entropy at the input size, backward, AdamW), as medians of ``--reps``, with each head's
ratio to DPT's time. ``--with-backbone`` also times the backbone's inference (batch 1) in the
same alternation and prints the whole segmenter's ratio to the DPT segmenter's. On shared cores
compare ratios, not seconds. The machine's load average is printed. Random weights: speed does
not depend on their values.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import time

import torch
import torch.nn.functional as F

from claravid.eval.inference.windows import natural_size
from claravid.models import backbone_spec, build_model
from claravid.models.heads.specs import HEAD_NAMES

NUM_CLASSES = 19  # the claravid palette, as the configs train it


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def _autocast(device: torch.device, amp: str):
    if amp == "off":
        return contextlib.nullcontext()
    return torch.autocast(device.type, dtype=torch.bfloat16)


def _heads(backbone: str, device: torch.device) -> dict[str, torch.nn.Module]:
    """The segmenters of every head on one random backbone (built once, shared)."""
    torch.manual_seed(0)
    models = {}
    for head in HEAD_NAMES:
        models[head] = build_model(backbone, NUM_CLASSES, head=head).to(device)
    shared = models["dpt"].backbone
    for model in models.values():
        model.backbone = shared
    return models


def bench(
    backbone: str,
    size: int,
    batch: int,
    reps: int,
    device: torch.device,
    amp: str,
    with_backbone: bool = False,
) -> None:
    models = _heads(backbone, device)
    p = backbone_spec(backbone).patch_size
    grid = size // p
    x = torch.randn(batch, 3, size, size, device=device)
    labels = torch.randint(0, NUM_CLASSES, (batch, size, size), device=device)
    taps = sorted({i for m in models.values() for i in m.layers})
    with torch.inference_mode(), _autocast(device, amp):
        computed = models["dpt"].backbone.get_intermediate_layers(x, taps, return_class_token=True)
    # Plain tensors (not inference tensors), so the heads can train on them.
    by_block = {
        i: (t.clone().float(), c.clone().float()) for i, (t, c) in zip(taps, computed, strict=True)
    }
    del computed
    params = {h: sum(q.numel() for q in m.head.parameters()) for h, m in models.items()}
    optimisers = {h: torch.optim.AdamW(m.head.parameters(), lr=1e-4) for h, m in models.items()}

    def infer(head: str) -> None:
        model = models[head].eval()
        feats = [(t[:1], c[:1]) for t, c in (by_block[i] for i in model.layers)]
        with torch.inference_mode(), _autocast(device, amp):
            model.head(feats, grid, grid, (size, size))

    def run_backbone() -> None:
        with torch.inference_mode(), _autocast(device, amp):
            models["dpt"].backbone.get_intermediate_layers(x[:1], taps, return_class_token=True)

    def train_step(head: str) -> None:
        model = models[head].train()
        feats = [by_block[i] for i in model.layers]
        with _autocast(device, amp):
            logits = model.head(feats, grid, grid, (size, size))
            loss = F.cross_entropy(logits.float(), labels)
        loss.backward()
        optimisers[head].step()
        optimisers[head].zero_grad(set_to_none=True)

    print(f"== heads on {backbone} features at {size}x{size} ({grid}x{grid} patches), "
          f"{device}, amp {amp}, {torch.get_num_threads()} threads, load average "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}")  # fmt: skip
    for name, fn, n in (("inference, batch 1", infer, 1), (f"training step, batch {batch}",
                                                            train_step, batch)):  # fmt: skip
        jobs = {head: (lambda head=head, fn=fn: fn(head)) for head in HEAD_NAMES}
        if with_backbone and fn is infer:
            jobs["backbone"] = run_backbone
        times: dict[str, list[float]] = {job: [] for job in jobs}
        for job in jobs.values():  # warm-up
            job()
        for _ in range(reps):
            for key, job in jobs.items():
                _sync(device)
                start = time.perf_counter()
                job()
                _sync(device)
                times[key].append(time.perf_counter() - start)
        median = {key: statistics.median(values) for key, values in times.items()}
        print(f"-- {name} (median of {reps}, alternated)")
        for head in HEAD_NAMES:
            t = median[head]
            print(f"{head:8} {params[head] / 1e6:7.2f} M params  {1000 * t:9.1f} ms  "
                  f"{n / t:7.2f} img/s  {t / median['dpt']:5.2f}x DPT's time")  # fmt: skip
        if "backbone" in median:
            whole = {head: median["backbone"] + median[head] for head in HEAD_NAMES}
            print(f"backbone {1000 * median['backbone']:9.1f} ms; whole segmenter: " + ", ".join(
                f"{head} {whole[head] / whole['dpt']:.2f}x" for head in HEAD_NAMES
            ) + " the DPT segmenter's time")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backbone", default="dinov3_vitl16")
    parser.add_argument("--size", type=int, help="input side (default: the natural size)")
    parser.add_argument("--batch", type=int, default=2, help="training step crops (>= 2)")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--amp", choices=("off", "bf16"), default="off")
    parser.add_argument("--with-backbone", action="store_true", help="whole-segmenter ratios")
    args = parser.parse_args(argv)
    size = args.size or natural_size(backbone_spec(args.backbone).patch_size)
    bench(args.backbone, size, max(2, args.batch), args.reps, torch.device(args.device), args.amp,
          args.with_backbone)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

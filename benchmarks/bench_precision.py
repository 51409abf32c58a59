"""PyTorch bf16 autocast vs float32 on this CPU: speed ratio and argmax agreement.

    .venv/bin/python benchmarks/bench_precision.py             # dinov2_vits14 + DPT, 630², batch 1
    .venv/bin/python benchmarks/bench_precision.py --reps 3 --size 448

What ``--precision bf16`` (or ``train.precision=bf16``) buys on a CPU: the segmenter's
forward under ``torch.autocast("cpu", dtype=torch.bfloat16)`` against float32, in the same run,
alternating the two so load from other processes hits both alike. Random weights (speed does not
depend on their values); agreement is the share of pixels whose argmax class is the same, on a
smooth random image (a real-looking input, not white noise). bf16 is fast only where the CPU
multiplies bf16 natively (AVX512-BF16, AMX): the script prints which of these flags it finds.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from claravid.models import build_model


def cpu_flags() -> list[str]:
    """The bf16-relevant x86 flags of this CPU (``/proc/cpuinfo``; empty elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return []
    words = set(text.split())
    return sorted(w for w in words if w == "avx512_bf16" or w.startswith("amx"))


def smooth_image(size: int, seed: int = 0) -> torch.Tensor:
    """A normalised [1,3,S,S] image of smooth blobs: coarse noise upsampled bicubically."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.randn(1, 3, size // 32 + 1, size // 32 + 1, generator=g)
    return F.interpolate(coarse, size=(size, size), mode="bicubic", align_corners=False)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--backbone", default="dinov2_vits14")
    p.add_argument("--size", type=int, default=630, help="input height and width (patch multiple)")
    p.add_argument("--reps", type=int, default=5, help="timed forwards per precision")
    p.add_argument("--classes", type=int, default=19)
    args = p.parse_args()

    flags = cpu_flags()
    print(f"CPU bf16 flags: {', '.join(flags) if flags else 'none (no AVX512-BF16, no AMX)'}")
    print(f"== {args.backbone} + DPT, {args.size}x{args.size}, batch 1, "
          f"{torch.get_num_threads()} threads, torch {torch.__version__}")  # fmt: skip
    torch.manual_seed(0)
    model = build_model(args.backbone, num_classes=args.classes).eval()
    x = smooth_image(args.size)

    def fp32() -> torch.Tensor:
        return model(x)

    def bf16() -> torch.Tensor:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            return model(x)

    times: dict[str, list[float]] = {"fp32": [], "bf16": []}
    with torch.inference_mode():
        ref, low = fp32(), bf16()  # warm-up, and the outputs compared below
        for _ in range(args.reps):
            for name, fn in (("fp32", fp32), ("bf16", bf16)):
                t = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t)
    agree = (ref.argmax(1) == low.float().argmax(1)).float().mean().item()
    diff = (low.float() - ref).abs().max().item()
    t32, t16 = statistics.median(times["fp32"]), statistics.median(times["bf16"])
    print(f"fp32 {t32 * 1000:8.0f} ms/image (baseline)")
    print(f"bf16 {t16 * 1000:8.0f} ms/image   speed ×{t32 / t16:.2f} vs fp32")
    print(f"argmax agreement bf16 vs fp32: {agree * 100:.2f} %   max |logit diff| {diff:.3g}")


if __name__ == "__main__":
    main()

"""What test-time augmentation costs: one copy against the ``dinov3`` and ``mmseg`` presets.

    .venv/bin/python benchmarks/bench_tta.py     # tiny DINOv3, 480x360, 128² windows
    .venv/bin/python benchmarks/bench_tta.py --size 960x720 --window 256 --reps 1

Random weights (speed does not depend on their values), one CPU thread, the same image and
windows for every run; the three are timed in turn on each repetition so that load from other
processes hits them alike, and the best of ``--reps`` is kept. The ratio to one copy is about
the number of copies times the mean of r² (a copy's windows grow with its area), rounded up by
whole windows. The cost depends on the image's size, not its content: the same in every
complexity bin.
"""

from __future__ import annotations

import argparse
import time

import torch

from claravid.eval import TTAConfig, WindowConfig
from claravid.eval.inference.windows import predict_labels
from claravid.infra.cli import parse_size
from claravid.models import build_model

TINY = {"embed_dim": 32, "depth": 4, "num_heads": 2}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=parse_size, default=(480, 360), help="WxH")
    parser.add_argument("--window", type=int, default=128)
    parser.add_argument("--reps", type=int, default=3)
    args = parser.parse_args()
    torch.manual_seed(0)
    torch.set_num_threads(1)
    model = build_model("dinov3_vits16", num_classes=8, backbone_kwargs=TINY, head="linear")
    model.eval()
    w, h = args.size
    image = torch.randint(0, 256, (3, h, w), dtype=torch.uint8)
    runs = {"one copy": None, "--tta dinov3": TTAConfig.preset("dinov3"),
            "--tta mmseg": TTAConfig.preset("mmseg")}  # fmt: skip
    best = dict.fromkeys(runs, float("inf"))
    for _ in range(args.reps):
        for name, tta in runs.items():
            config = WindowConfig(size=args.window, batch_size=8, tta=tta)
            start = time.perf_counter()
            predict_labels(model, image, config)
            best[name] = min(best[name], time.perf_counter() - start)
    print(f"image {w}x{h}, windows {args.window}², tiny dinov3_vits16 + linear head, 1 thread")
    for name, seconds in best.items():
        copies = 1 if runs[name] is None else len(runs[name].copies())  # type: ignore[union-attr]
        ratio = seconds / best["one copy"]
        print(f"{name:>13} ({copies:2d} copies): {seconds * 1000:7.0f} ms  {ratio:5.1f}x")


if __name__ == "__main__":
    main()

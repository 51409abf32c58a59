"""Speed of the segmenter: CPU eager vs onnxruntime, and (with CUDA) the training step.

    PYTHONPATH=. python benchmarks/bench_model.py              # CPU part, then GPU if present
    PYTHONPATH=. python benchmarks/bench_model.py --skip-cpu --batch 16

CPU: dinov2_vits14 + DPT head at 630x630, batch 1, PyTorch eager fp32 vs onnxruntime (fixed-size
export), in the same run; target ratio ort/eager speed >= 1.
GPU: dinov2_vitl14 + head at 630x630, training step (frozen backbone forward + head forward and
backward + AdamW) in fp32 and bf16 autocast, torch.compile off/on; images/s and achieved TFLOP/s
counting the backbone as ~1.63 TFLOP per image (2 FLOP per multiply-add).
Random weights: speed does not depend on their values.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch

from claravid.models import OnnxSegmenter, build_model, export_onnx

BACKBONE_TFLOP_630 = 1.63  # ViT-L/14, 2026 tokens, forward


def _time(fn, warmup: int, reps: int, sync=lambda: None) -> float:
    """Median seconds per call."""
    for _ in range(warmup):
        fn()
    sync()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def bench_cpu(size: int, reps: int) -> None:
    print(f"== CPU: dinov2_vits14 + DPT, {size}x{size}, batch 1, {torch.get_num_threads()} threads")
    model = build_model("dinov2_vits14", num_classes=19).eval()
    x = torch.randn(1, 3, size, size)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.onnx"
        t = time.perf_counter()
        export_onnx(model, path, size, size)
        print(f"export + check: {time.perf_counter() - t:.1f} s")
        runner = OnnxSegmenter(path, providers=["CPUExecutionProvider"])
        xn = x.numpy()
        # Alternate the two so that load from other processes hits both alike.
        eager, ort = [], []
        with torch.inference_mode():
            model(x), runner(xn)  # warm-up
            for _ in range(reps):
                eager.append(_time(lambda: model(x), warmup=0, reps=1))
                ort.append(_time(lambda: runner(xn), warmup=0, reps=1))
    e, o = statistics.median(eager), statistics.median(ort)
    print(f"PyTorch eager fp32: {e * 1000:8.1f} ms/image (median of {reps})")
    print(f"onnxruntime:        {o * 1000:8.1f} ms/image (median of {reps})")
    print(f"ratio ort speed / eager speed: {e / o:.2f}x (target >= 1)")


def bench_gpu(batch: int, size: int, reps: int) -> None:
    if not torch.cuda.is_available():
        print("== GPU: skipped (CUDA not available)")
        return
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    print(f"== GPU: {torch.cuda.get_device_name()}, dinov2_vitl14 + DPT, {size}x{size}, b{batch}")
    x = torch.randn(batch, 3, size, size, device="cuda").to(memory_format=torch.channels_last)
    y = torch.randint(0, 19, (batch, size, size), device="cuda")
    base = None
    for compile_ in (False, True):
        for dtype in (torch.float32, torch.bfloat16):
            model = build_model("dinov2_vitl14", num_classes=19).cuda().train()
            model = model.to(memory_format=torch.channels_last)
            opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=1e-4)
            fwd = torch.compile(model) if compile_ else model

            def step(fwd=fwd, opt=opt, dtype=dtype):
                with torch.autocast("cuda", dtype=dtype, enabled=dtype != torch.float32):
                    loss = torch.nn.functional.cross_entropy(fwd(x), y)
                loss.backward()
                opt.step()
                opt.zero_grad(set_to_none=True)

            torch.cuda.reset_peak_memory_stats()
            sec = _time(step, warmup=3, reps=reps, sync=torch.cuda.synchronize)
            ips = batch / sec
            base = base or ips
            mem = torch.cuda.max_memory_allocated() / 2**30
            print(
                f"compile={compile_!s:5} {str(dtype).removeprefix('torch.'):8}: "
                f"{ips:7.1f} img/s  {ips * BACKBONE_TFLOP_630:6.1f} backbone TFLOP/s  "
                f"peak {mem:5.1f} GiB  ({ips / base:.2f}x fp32 eager)"
            )
            del model, opt, fwd
            torch.cuda.empty_cache()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=630)
    parser.add_argument("--reps", type=int, default=5, help="timed repetitions (CPU)")
    parser.add_argument("--batch", type=int, default=16, help="GPU batch (8-32)")
    parser.add_argument("--gpu-reps", type=int, default=10)
    parser.add_argument("--skip-cpu", action="store_true")
    args = parser.parse_args(argv)
    if not args.skip_cpu:
        bench_cpu(args.size, args.reps)
    bench_gpu(args.batch, args.size, args.gpu_reps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

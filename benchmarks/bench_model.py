"""Speed of the segmenter: CPU eager vs onnxruntime, and (with CUDA) the training step.

    PYTHONPATH=. python benchmarks/bench_model.py              # CPU part, then GPU if present
    PYTHONPATH=. python benchmarks/bench_model.py --skip-cpu --batch 16
    PYTHONPATH=. python benchmarks/bench_model.py --precisions --skip-gpu    # fp16/int8 exports
    PYTHONPATH=. python benchmarks/bench_model.py --precisions --skip-gpu --demo \
        runs/demo/train/best.pt --demo-data runs/demo/data      # + agreement of a trained model

Precisions (``--precisions``): the files users get. A random-init dinov2_vits14 + DPT segmenter
(19 classes, as the claravid configs) is saved with ``save_checkpoint``; ``claravid-export``'s own
function writes it at 630x630 in fp32, fp16, int8 dynamic (MatMul/Gemm), int8 dynamic per
channel and int8 static QDQ (calibrated on smooth random images written as PNGs); each file is
loaded as ``claravid-eval --onnx`` loads it (``OnnxSegmenter``, CPU, torch's thread count) and
they are timed in turn (A B C A B C, batch 1) in one run: the median and the best of
``--precision-reps`` as ratios of speed against fp32 (target int8 >= 1.5x), and the argmax
agreement with PyTorch. The machine's load average is printed: on shared cores, compare
ratios, not milliseconds, and read the medians: a run takes 2-3x longer whenever another
process holds a core, so a best-of pairs a lucky int8 run with an unlucky fp32 one (best-of
ratios of 1.5-1.65x were seen for files whose medians gave 1.2x); best-of is fair only on a
quiet machine.
On random weights the agreement says little about accuracy; ``--demo`` exports a trained
checkpoint the same way (static QDQ calibrated on its data) and adds the agreement on real
validation frames.

CPU: dinov2_vits14 + DPT head at 630x630, batch 1, PyTorch eager fp32 vs onnxruntime (fixed-size
export), in the same run; target ratio ort/eager speed >= 1.

Backbones (``--backbones``): DINOv3-L/16 + DPT at 640x640 against DINOv2-L/14 + DPT at 630x630
(each model's natural size, the crops and windows of the paper configs: 1,600 tokens against
2,025), batch 1, random init, in one run: PyTorch eager fp32 forward time (medians of
alternated runs; target DINOv3 <= 0.8x DINOv2's time) and peak memory (each forward in a fresh
spawned process: its peak resident set, and the rise above the built model). Then onnxruntime
(fixed-size fp32 exports, checked) of both; exporting two ViT-L takes longer than a short run
here, so ``--ort-depth`` (default 6 of 24 blocks, taps 1, 2, 4, 5) builds both with fewer
blocks of the same width (the per-block costs compare alike); ``--ort-depth 24`` exports the
full models, ``--ort-depth 0`` skips them. ``--backbone dinov3_vits16 --precisions`` runs the
precisions part on a DINOv3 segmenter at its natural size, and adds which operators of the
int8 file stay float and where ONNX Runtime spends its time (its profiler, per operator type).
GPU: dinov2_vitl14 + head at 630x630, training step (frozen backbone forward + head forward and
backward + AdamW) in fp32 and bf16 autocast, torch.compile off/on; images/s and achieved TFLOP/s
counting the backbone as ~1.63 TFLOP per image (2 FLOP per multiply-add).
Random weights: speed does not depend on their values.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from claravid.models import OnnxSegmenter, backbone_spec, build_model, export_onnx
from claravid.models.export.onnx import ExportSettings
from claravid.models.grid import natural_size

BACKBONE_TFLOP_630 = 1.63  # ViT-L/14, 2026 tokens, forward
NUM_CLASSES = 19  # the claravid palette, as the configs train it


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
        export_onnx(model, path, ExportSettings(height=size, width=size))
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


#: The precisions compared, as ``claravid-export`` flags (fp32 first: the base of the ratios).
EXPORTS: dict[str, list[str]] = {
    "ORT fp32": [],
    "ORT fp16": ["--dtype", "fp16"],
    "ORT int8 dynamic": ["--dtype", "int8"],
    "ORT int8 dynamic per-channel": ["--dtype", "int8", "--per-channel"],
    "ORT int8 static QDQ": ["--dtype", "int8", "--calibration", "{calibration}"],
}
CALIBRATION_IMAGES = 8


def _calibration_folder(folder: Path, size: tuple[int, int], count: int) -> Path:
    """``count`` smooth random photos (PNG) for ``--calibration`` (no dataset at hand)."""
    import cv2

    from claravid.models.export.metadata import normalisation_from_config
    from claravid.models.export.onnx import smooth_images

    norm = normalisation_from_config(None)
    mean = np.asarray(norm["mean"], np.float32).reshape(3, 1, 1)
    std = np.asarray(norm["std"], np.float32).reshape(3, 1, 1)
    folder.mkdir()
    for seed in range(count):
        x = smooth_images((1, 3, *size), norm, seed=100 + seed)[0]
        rgb = np.clip(np.rint((x * std + mean) * 255), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{seed:02d}.png"), rgb.transpose(1, 2, 0)[..., ::-1])
    return folder


def _export_like_users(
    checkpoint: Path, folder: Path, size: tuple[int, int], calibration: Path, images: int
) -> dict[str, Path]:
    """The files ``claravid-export --checkpoint CKPT --size WxH [flags]`` writes, one per
    precision, written by the console script's own function (export time printed)."""
    from claravid.eval.cli.export import main as claravid_export

    h, w = size
    out = {}
    for i, (name, flags) in enumerate(EXPORTS.items()):
        path = folder / f"v{i}.onnx"
        flags = [f.format(calibration=calibration) for f in flags]
        if "--calibration" in flags:
            flags += ["--calibration-images", str(images)]
        # --no-check: the check reads the finished file and never changes it; the agreement
        # with PyTorch is measured below anyway (and static QDQ on random weights fails it).
        argv = ["--checkpoint", str(checkpoint), "-o", str(path), "--size", f"{w}x{h}"]
        t = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            status = claravid_export([*argv, *flags, "--no-check"])
        if status != 0:
            raise RuntimeError(f"claravid-export {' '.join(argv + flags)} failed ({status})")
        shown = " ".join(flags).replace(str(calibration), "CALIBRATION") or "--dtype fp32"
        print(f"{name:30s} written in {time.perf_counter() - t:5.1f} s  (claravid-export {shown})")
        out[name] = path
    return out


def _runners(files: dict[str, Path], threads: int) -> dict[str, Any]:
    """Each file loaded as ``claravid-eval --onnx FILE`` loads it on a CPU."""
    from claravid.models.export.runtime import OnnxSegmenter, resolve_providers

    return {n: OnnxSegmenter(p, providers=resolve_providers("cpu"), threads=threads)
            for n, p in files.items()}  # fmt: skip


def _agreement(a, b) -> float:
    return float((a.argmax(1) == b.argmax(1)).mean())


def _alternate(runners: dict[str, Any], x: np.ndarray, reps: int):
    """Outputs, and seconds per call of each runner, timed in turn (A B C A B C ...) so that
    load from other processes hits all alike; one warm-up call each."""
    outs = {name: run(x) for name, run in runners.items()}
    times: dict[str, list[float]] = {name: [] for name in runners}
    for _ in range(reps):
        for name, run in runners.items():
            times[name].append(_time(lambda run=run: run(x), warmup=0, reps=1))
    return outs, times


def bench_precisions(
    size: int, reps: int, num_classes: int = NUM_CLASSES, backbone: str = "dinov2_vits14"
) -> None:
    """The files ``claravid-export`` writes at each precision, run as ``claravid-eval --onnx``
    runs them: speed ratio against fp32 and argmax agreement with PyTorch; then what stays
    float in the int8 file and where ONNX Runtime spends its time."""
    from claravid.models.checkpoint import save_checkpoint
    from claravid.models.export.metadata import normalisation_from_config
    from claravid.models.export.onnx import smooth_images

    threads = torch.get_num_threads()
    print(
        f"== precisions: {backbone} + DPT ({num_classes} classes, random init), "
        f"{size}x{size}, batch 1, {threads} threads, load average {os.getloadavg()[0]:.2f}"
    )
    torch.manual_seed(0)
    model = build_model(backbone, num_classes=num_classes).eval()
    x = smooth_images((1, 3, size, size), normalisation_from_config(None), seed=1)
    with torch.inference_mode():
        expected = model(torch.from_numpy(x)).numpy()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        checkpoint = save_checkpoint(model, folder / "random-init.pt")
        calibration = _calibration_folder(folder / "calibration", (size, size), CALIBRATION_IMAGES)
        files = _export_like_users(
            checkpoint, folder, (size, size), calibration, CALIBRATION_IMAGES
        )
        outs, times = _alternate(_runners(files, threads), x, reps)
        int8_report(files["ORT int8 dynamic"], x, threads)
    base, base_best = statistics.median(times["ORT fp32"]), min(times["ORT fp32"])
    for name, values in times.items():
        t, best = statistics.median(values), min(values)
        diff = float(abs(outs[name] - expected).max())
        print(
            f"{name:30s} {t * 1000:8.1f} ms/image  {base / t:5.2f}x ORT fp32 "
            f"(best of {reps}: {best * 1000:7.1f} ms, {base_best / best:5.2f}x)  "
            f"agreement {100 * _agreement(outs[name], expected):6.2f} %  max|dlogit| {diff:.3g}"
        )
    print(
        f"ratios: medians (and bests) of {reps} alternated runs; "
        "target: ORT int8 >= 1.5x ORT fp32 (random weights: agreement is not accuracy)"
    )


def bench_demo(checkpoint: Path, data: Path, frames: int) -> None:
    """Argmax agreement of the fp16 / int8 exports of a trained checkpoint on val frames."""
    from claravid.eval.inference.sources import load_source, resolve_settings
    from claravid.eval.inference.windows import predict_labels
    from claravid.eval.inputs.datasets import open_data

    source = load_source(checkpoint)
    settings = resolve_settings(source)
    data_ = open_data(data, split="val", palette=settings.palette)
    h, w = settings.window.size
    print(f"== trained {checkpoint}: {frames} val frames, windows {h}x{w}")
    with tempfile.TemporaryDirectory() as tmp:
        # As a user ships it: claravid-export on the checkpoint, static QDQ calibrated on
        # crops of the data's own frames.
        files = _export_like_users(checkpoint, Path(tmp), (h, w), data, CALIBRATION_IMAGES)
        runners = _runners(files, torch.get_num_threads())
        agree = {name: [] for name in runners}
        for i in range(min(frames, len(data_))):
            image = data_.dataset[i]["image"]
            with torch.inference_mode():
                ref = predict_labels(source.model, image, settings.window)
            for name, run in runners.items():
                pred = predict_labels(run, image, settings.window)
                agree[name].append(float((pred == ref).float().mean()))
    for name, values in agree.items():
        print(f"{name:30s} argmax agreement with PyTorch {100 * statistics.mean(values):6.2f} %")


#: The pair compared by ``--backbones``, each at its natural size.
PAIR = ("dinov2_vitl14", "dinov3_vitl16")


def _segmenter(name: str, depth: int | None = None):
    """A random-init segmenter of ``name`` (19 classes); ``depth`` blocks instead of the
    backbone's, tapping 4 of them evenly as the full model does."""
    torch.manual_seed(0)
    if depth is None:
        return build_model(name, num_classes=NUM_CLASSES).eval()
    taps = [round(depth * k / 4) - 1 for k in (1, 2, 3, 4)]
    return build_model(name, num_classes=NUM_CLASSES, backbone_kwargs={"depth": depth},
                       layers=taps).eval()  # fmt: skip


def _rss_kib() -> int:
    """This process's resident set now, KiB (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def _peak_child(name: str, size: int, out) -> None:
    import resource

    model = _segmenter(name)
    x = torch.randn(1, 3, size, size)  # normalised-looking (zeros warn of raw pixels)
    built = _rss_kib()
    with torch.inference_mode():
        model(x)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    out.put((peak, peak - built))


def _peak_memory(name: str, size: int) -> tuple[float, float]:
    """(peak resident GiB, rise above the built model GiB) of one eager forward, measured in a
    fresh interpreter so that nothing else counts (spawned: a child forked after this process
    ran torch's OpenMP threads, the CPU section's, hangs in its first parallel region)."""
    import multiprocessing as mp

    context = mp.get_context("spawn")
    out = context.Queue()
    job = context.Process(target=_peak_child, args=(name, size, out))
    job.start()
    peak, rise = out.get()
    job.join()
    return peak / 2**20, rise / 2**20


def bench_backbones(reps: int, ort_depth: int) -> None:
    """DINOv3-L/16 at 640² against DINOv2-L/14 at 630²: eager time and memory, then ORT."""
    threads = torch.get_num_threads()
    sizes = {name: natural_size(backbone_spec(name).patch_size) for name in PAIR}
    tokens = {n: (sizes[n] // backbone_spec(n).patch_size) ** 2 for n in PAIR}
    which = ", ".join(f"{n} + DPT at {sizes[n]}² ({tokens[n]} tokens)" for n in PAIR)
    print(f"== backbones: {which}; batch 1, {threads} threads, "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    base = PAIR[0]
    for name in PAIR:
        peak, rise = _peak_memory(name, sizes[name])
        print(f"{name:16s} eager fp32 peak memory {peak:5.2f} GiB resident, "
              f"{rise:5.2f} GiB above the built model")  # fmt: skip
    nets = {n: _segmenter(n) for n in PAIR}
    inputs = {n: torch.randn(1, 3, sizes[n], sizes[n]) for n in PAIR}
    times: dict[str, list[float]] = {n: [] for n in PAIR}
    with torch.inference_mode():
        for n in PAIR:
            nets[n](inputs[n])  # warm-up
        for _ in range(reps):
            for n in PAIR:
                times[n].append(_time(lambda n=n: nets[n](inputs[n]), warmup=0, reps=1))
    nets.clear()  # free 2 x 1.2 GB before the exports
    for n in PAIR:
        t = statistics.median(times[n])
        ratio = t / statistics.median(times[base])
        print(f"{n:16s} eager fp32 {t * 1000:8.0f} ms/image (median of {reps}, best "
              f"{min(times[n]) * 1000:.0f})  {ratio:.2f}x {base}'s time")  # fmt: skip
    print(f"target: {PAIR[1]} <= 0.8x {base}'s time")
    if ort_depth == 0:
        return
    depth = ort_depth if ort_depth < 24 else None
    what = "full depth" if depth is None else f"depth {depth} of 24 (same width, heads, head)"
    print(f"-- onnxruntime, fixed-size fp32 exports, {what}")
    runners, eager = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in PAIR:
            model = _segmenter(n, depth)
            path = Path(tmp) / f"{n}.onnx"
            start = time.perf_counter()
            export_onnx(model, path, ExportSettings(height=sizes[n], width=sizes[n]))
            print(f"{n:16s} export + check {time.perf_counter() - start:6.1f} s")
            runners[n] = OnnxSegmenter(path, providers=["CPUExecutionProvider"], threads=threads)
            eager[n] = model
        ort: dict[str, list[float]] = {n: [] for n in PAIR}
        torch_t: dict[str, list[float]] = {n: [] for n in PAIR}
        xs = {n: inputs[n].numpy() for n in PAIR}
        with torch.inference_mode():
            for n in PAIR:
                runners[n](xs[n])
            for _ in range(reps):
                for n in PAIR:
                    ort[n].append(_time(lambda n=n: runners[n](xs[n]), warmup=0, reps=1))
                    torch_t[n].append(_time(lambda n=n: eager[n](inputs[n]), warmup=0, reps=1))
    for n in PAIR:
        o, e = statistics.median(ort[n]), statistics.median(torch_t[n])
        ratio = o / statistics.median(ort[base])
        print(f"{n:16s} ORT fp32 {o * 1000:8.0f} ms/image, eager {e * 1000:8.0f} ms "
              f"(medians of {reps})  ORT {ratio:.2f}x {base}'s ORT time")  # fmt: skip


def int8_report(path: Path, x: np.ndarray, threads: int) -> None:
    """Which operators of an int8 file are integer and which stay float, and where ONNX Runtime
    spends its time (its profiler, summed per operator type over a few runs)."""
    import json

    import onnx
    import onnxruntime as ort

    graph = onnx.load(str(path), load_external_data=False).graph
    counts: dict[str, int] = {}
    for node in graph.node:
        counts[node.op_type] = counts.get(node.op_type, 0) + 1
    integer = {"MatMulInteger", "DynamicQuantizeLinear", "DynamicQuantizeMatMul", "QLinearConv",
               "QLinearMatMul", "QuantizeLinear", "DequantizeLinear", "ConvInteger",
               "MatMulIntegerToFloat"}  # fmt: skip
    shown = sorted(counts.items(), key=lambda kv: -kv[1])
    print(
        "   int8 graph, quantised ops: " + ", ".join(f"{k} {v}" for k, v in shown if k in integer)
    )
    print("   int8 graph, float ops:     " + ", ".join(
        f"{k} {v}" for k, v in shown if k not in integer and v > 0)[:400])  # fmt: skip
    options = ort.SessionOptions()
    options.enable_profiling = True
    options.intra_op_num_threads = threads
    with tempfile.TemporaryDirectory() as tmp:
        options.profile_file_prefix = str(Path(tmp) / "profile")
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        name = session.get_inputs()[0].name
        for _ in range(3):
            session.run(None, {name: x})
        trace = json.loads(Path(session.end_profiling()).read_text())
    spent: dict[str, float] = {}
    for event in trace:
        op = (event.get("args") or {}).get("op_name")
        if event.get("cat") == "Node" and op and event.get("name", "").endswith("_kernel_time"):
            spent[op] = spent.get(op, 0.0) + event["dur"]
    total = sum(spent.values()) or 1.0
    top = sorted(spent.items(), key=lambda kv: -kv[1])[:8]
    print("   int8 time per op type: " + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in top))


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
    parser.add_argument("--size", type=int, help="input side (default: the model's natural size)")
    parser.add_argument("--backbone", default="dinov2_vits14", help="of --precisions")
    parser.add_argument(
        "--backbones", action="store_true", help="DINOv3-L/16 at 640 vs DINOv2-L/14 at 630"
    )
    parser.add_argument(
        "--ort-depth",
        type=int,
        default=6,
        help="--backbones: blocks of the ORT models (24: all; 0: no ORT part)",
    )
    parser.add_argument("--reps", type=int, default=5, help="timed repetitions (CPU)")
    parser.add_argument(
        "--precision-reps", type=int, default=10, help="timed repetitions of each precision"
    )
    parser.add_argument("--batch", type=int, default=16, help="GPU batch (8-32)")
    parser.add_argument("--gpu-reps", type=int, default=10)
    parser.add_argument("--skip-cpu", action="store_true", help="no eager-vs-ORT part")
    parser.add_argument("--skip-gpu", action="store_true")
    parser.add_argument("--precisions", action="store_true", help="ORT fp32 vs fp16/int8")
    parser.add_argument("--demo", type=Path, help="trained checkpoint: agreement of its exports")
    parser.add_argument("--demo-data", type=Path, default=Path("runs/demo/data"))
    parser.add_argument("--demo-frames", type=int, default=8)
    args = parser.parse_args(argv)
    size = args.size or natural_size(backbone_spec(args.backbone).patch_size)
    if not args.skip_cpu:
        bench_cpu(args.size or 630, args.reps)
    if args.backbones:
        bench_backbones(args.reps, args.ort_depth)
    if args.precisions:
        bench_precisions(size, args.precision_reps, backbone=args.backbone)
    if args.demo is not None:
        bench_demo(args.demo, args.demo_data, args.demo_frames)
    if not args.skip_gpu:
        bench_gpu(args.batch, args.size or 630, args.gpu_reps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Window decode of a JPEG vs the full decode it replaces, on full-size 4:2:0 frames, one core.

Run: ``.venv/bin/python benchmarks/bench_jpeg_region.py [--frames 2] [--repeats 5]``

Frames: ``--frames`` 4032×3024 frames from the scene generator (its JPEGs: OpenCV, quality 95,
4:2:0, about 2.8 MB) plus one textured frame (gradients + multi-scale noise, also quality 95
4:2:0, a harder case: bigger file, more entropy data to read). Per frame, the median over
``--repeats`` of:
  - ``cv2.imread`` of the whole frame (the baseline);
  - ``read_rgb``, the project's full decode today (OpenCV straight to RGB);
  - the libjpeg window decoder over the whole frame (``read_rgb_window(p, 0, 0, W, H)``);
  - a random 630×630 window (a training crop), a new window per repeat;
  - the same window through the fallback (full decode + slice, no C extension).
Every time includes reading the file (from the page cache). Prints ms and the ratio to the
baseline measured in the same run, then the window decoder's gain over the fallback (full
decode plus crop, the slow path training falls back to); checks each window against the full
decode once.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from claravid.io import jpeg_region
from claravid.io.modalities import read_rgb
from claravid.synth import synthesize

WIDTH, HEIGHT, CROP = 4032, 3024, 630


def textured_frame(path: Path, seed: int) -> Path:
    """Gradients plus noise at several scales, so that every block and chroma sample varies."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    image = np.stack([xx / WIDTH * 255, yy / HEIGHT * 255, (xx + yy) / (WIDTH + HEIGHT) * 255], -1)
    for scale, amplitude in ((64, 60), (8, 25), (1, 8)):
        small = rng.normal(0, amplitude, (HEIGHT // scale, WIDTH // scale, 3)).astype(np.float32)
        image += cv2.resize(small, (WIDTH, HEIGHT), interpolation=cv2.INTER_CUBIC)
    bgr = np.clip(image, 0, 255).astype(np.uint8)[..., ::-1]
    cv2.imwrite(str(path), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])  # OpenCV's default: 4:2:0
    return path


def median_ms(function: Callable[[int], object], repeats: int) -> float:
    times = []
    for repeat in range(repeats):
        start = time.perf_counter()
        function(repeat)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000


def bench_frame(path: Path, repeats: int, seed: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    windows = [
        (int(rng.integers(WIDTH - CROP + 1)), int(rng.integers(HEIGHT - CROP + 1)))
        for _ in range(repeats)
    ]
    full = read_rgb(path)
    for x, y in windows:  # the benchmark is only worth something if the pixels are the same
        window = jpeg_region.read_rgb_window(path, x, y, CROP, CROP)
        assert np.array_equal(window, full[y : y + CROP, x : x + CROP]), (path, x, y)

    def fallback(i: int) -> None:
        native, jpeg_region._native = jpeg_region._native, None
        try:
            jpeg_region.read_rgb_window(path, *windows[i], CROP, CROP)
        finally:
            jpeg_region._native = native

    return {
        "cv2.imread full frame (baseline)": median_ms(
            lambda i: cv2.imread(str(path), cv2.IMREAD_COLOR), repeats
        ),
        "read_rgb full frame (today)": median_ms(lambda i: read_rgb(path), repeats),
        "libjpeg full frame": median_ms(
            lambda i: jpeg_region.read_rgb_window(path, 0, 0, WIDTH, HEIGHT), repeats
        ),
        f"libjpeg {CROP}×{CROP} window": median_ms(
            lambda i: jpeg_region.read_rgb_window(path, *windows[i], CROP, CROP), repeats
        ),
        f"fallback {CROP}×{CROP} window": median_ms(fallback, repeats),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=2, help="generator frames (default 2)")
    parser.add_argument("--repeats", type=int, default=5, help="timings per frame (default 5)")
    args = parser.parse_args()
    cv2.setNumThreads(1)  # one core, as one DataLoader worker has
    if jpeg_region.decoder() != jpeg_region.REGION_DECODE:
        raise SystemExit(f"claravid.io._jpeg_region is not built: {jpeg_region.decoder()}")

    with tempfile.TemporaryDirectory() as tmp:
        root = synthesize(
            Path(tmp) / "synth", seed=0, frames_per_viewpoint=args.frames,
            size=(WIDTH, HEIGHT), missions="urban_1", altitude="low", direction="h",
        )  # fmt: skip
        frames = sorted(root.rglob("left_rgb/**/*.jpg"))[: args.frames]
        frames.append(textured_frame(Path(tmp) / "textured.jpg", seed=1))
        results: dict[str, list[float]] = {}
        for index, path in enumerate(frames):
            size_mb = path.stat().st_size / 1e6
            print(f"frame {index}: {path.name}, {size_mb:.1f} MB", flush=True)
            for name, ms in bench_frame(path, args.repeats, seed=index).items():
                results.setdefault(name, []).append(ms)

    # Other processes on the machine slow every row alike; the load says how far to trust ms.
    print(f"\none core, {WIDTH}×{HEIGHT} 4:2:0 JPEG, file read included, median of "
          f"{args.repeats} per frame; load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"  {'':34s} " + " ".join(f"{f'frame {i}':>9s}" for i in range(len(frames))))
    baseline = results["cv2.imread full frame (baseline)"]
    for name, values in results.items():
        ms = " ".join(f"{v:6.1f} ms" for v in values)
        speed = statistics.median(b / v for b, v in zip(baseline, values, strict=True))
        print(f"  {name:34s} {ms}   {speed:5.2f}× the baseline's speed (median)")
    window, fallback = (
        results[f"libjpeg {CROP}×{CROP} window"],
        results[f"fallback {CROP}×{CROP} window"],
    )
    gain = statistics.median(f / w for f, w in zip(fallback, window, strict=True))
    print(f"\n{CROP}×{CROP} window: the C extension is {gain:.1f}× as fast as OpenCV's full decode "
          "plus crop (median over the frames; docs/data.md states this figure)")  # fmt: skip


if __name__ == "__main__":
    main()

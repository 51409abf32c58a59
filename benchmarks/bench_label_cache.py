"""Speed and size of the label cache against decoding the panoptic PNG, in one run, one core.

    PYTHONPATH=. python benchmarks/bench_label_cache.py [--frames 2] [--windows 200]

Generates full-size 4032×3024 ClaraVid frames (``claravid.synth``: roads, buildings, vehicles,
some of them moving; panoptic PNG + dynamic mask) in a temp folder, pins itself to one CPU, and
prints the median milliseconds per frame of:

1. baseline: ``read_label_codes(pan, dyn)``, decoding the panoptic PNG (and dynamic mask)
   whole, what every epoch pays without a cache (the panoptic PNG alone beside it);
2. ``LabelCache.prepare`` of one frame into an empty cache: decode + encode + write
   (target <= 1.3× the baseline);
3. a warm 630×630 ``read_window`` at random positions (target: a few ms);
4. a whole-frame ``LabelCache.read`` from the TIFF entry, and today's whole-frame read of the
   single-channel PNG entry the cache used to write (``cv2.imread``, compression 3);

with ratios to the baseline measured in the same run, the entry size per frame (TIFF and the
former PNG), and the same figures for tile sizes 128 and 512 (why 256). Takes about a minute.
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
import numpy as np

from claravid.data.index import list_frames
from claravid.data.label_cache import LabelCache
from claravid.io.labels import read_label_codes
from claravid.synth import synthesize

TILES = (256, 128, 512)  # the chosen size first


def _median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def _one_core() -> str:
    cv2.setNumThreads(1)
    if hasattr(os, "sched_setaffinity"):
        cpu = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return f"pinned to CPU {cpu}"
    return "not pinned (no sched_setaffinity here)"


def _tile_figures(sources, tile: int, tmp: Path, windows: list, repeats: int) -> dict:
    prep = []
    for i in range(repeats):
        cache = LabelCache(tmp / f"prep-{tile}-{i}", tile_size=tile)
        start = time.perf_counter()
        cache.prepare(sources)
        prep.append((time.perf_counter() - start) / len(sources))
    window_ms = []
    for pan, dyn in sources:
        cache.read_window(pan, dyn, 0, 0, 8, 8)  # warm: the entry's header parsed once
        for x, y in windows:
            start = time.perf_counter()
            cache.read_window(pan, dyn, x, y, 630, 630)
            window_ms.append(time.perf_counter() - start)
    whole = statistics.median(_median_ms(lambda p=p, d=d: cache.read(p, d), repeats)
                              for p, d in sources)  # fmt: skip
    size = sum(p.stat().st_size for p in cache.directory.rglob("*.tif")) / len(sources)
    return {
        "prepare": statistics.median(prep) * 1e3,
        "window": statistics.median(window_ms) * 1e3,
        "whole": whole,
        "size": size,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--windows", type=int, default=200, help="random 630×630 windows")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    pinned = _one_core()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        start = time.perf_counter()
        synthesize(tmp / "root", seed=7, frames_per_viewpoint=args.frames, missions="urban_1",
                   altitude="low", direction="h")  # fmt: skip
        frames = list_frames(tmp / "root", fields=["pan_seg", "dynamic_mask"])
        sources = [(f.paths["pan_seg"], f.paths["dynamic_mask"]) for f in frames]
        print(f"{len(sources)} generated 4032×3024 frames in {time.perf_counter() - start:.0f} s; "
              f"{pinned}; median ms per frame")  # fmt: skip

        base = statistics.median(
            _median_ms(lambda p=p, d=d: read_label_codes(p, d), args.repeats) for p, d in sources
        )
        pan_only = statistics.median(
            _median_ms(lambda p=p: read_label_codes(p), args.repeats) for p, _ in sources
        )
        png_ms, png_size = [], []
        for i, (pan, dyn) in enumerate(sources):  # the former cache entry: a codes PNG
            path = tmp / f"codes-{i}.png"
            cv2.imwrite(str(path), read_label_codes(pan, dyn), [cv2.IMWRITE_PNG_COMPRESSION, 3])
            png_size.append(path.stat().st_size)
            flag = cv2.IMREAD_UNCHANGED
            png_ms.append(_median_ms(lambda p=path, f=flag: cv2.imread(str(p), f), args.repeats))

        rng = np.random.default_rng(0)
        windows = [(int(rng.integers(0, 4032 - 630 + 1)), int(rng.integers(0, 3024 - 630 + 1)))
                   for _ in range(args.windows)]  # fmt: skip
        pan_size = statistics.mean(p.stat().st_size for p, _ in sources)
        figures = {t: _tile_figures(sources, t, tmp, windows, args.repeats) for t in TILES}

    def row(name: str, ms: float, target: str = "") -> None:
        print(f"  {name:<52} {ms:8.2f} ms  {ms / base:6.3f}× baseline  {target}")

    print(f"  {'baseline: read_label_codes(pan, dyn), PNGs decoded whole':<52} {base:8.2f} ms")
    row("(panoptic PNG alone: read_label_codes(pan))", pan_only)
    f = figures[256]
    row("prepare one frame (decode + encode + write), tile 256", f["prepare"], "target <= 1.3×")
    row("warm read_window 630×630, tile 256", f["window"], "target: a few ms")
    row("whole-frame LabelCache.read (TIFF), tile 256", f["whole"])
    row("whole-frame read of the former PNG entry", statistics.median(png_ms))
    print(f"  entry size per frame: TIFF {f['size'] / 1e3:.0f} kB (tile 256), former PNG "
          f"{statistics.mean(png_size) / 1e3:.0f} kB, panoptic PNG "
          f"{pan_size / 1e3:.0f} kB")  # fmt: skip
    print("  tile size:   prepare ms   window ms   whole ms   kB/frame")
    for tile, f in figures.items():
        print(f"  {tile:>9}   {f['prepare']:10.1f}   {f['window']:9.2f}   {f['whole']:8.1f}   "
              f"{f['size'] / 1e3:8.0f}")  # fmt: skip


if __name__ == "__main__":
    main()

"""Speed and memory of claravid.dsp against the official np.histogram2d algorithm, in one run.

    PYTHONPATH=. python benchmarks/bench_dsp.py [--images 2]

Makes textured 4032x3024 JPEGs (quality 90) in a temp folder, then prints:
1. kernel: delentropy of a decoded, blurred image vs the official formulation (same value);
   and its histogram alone: the C extension (``claravid.dsp._deldensity``) vs the OpenCV + numpy
   path that counts without it (same counts), on the same gradients;
2. per file: decode + blur + delentropy vs the bare greyscale decode of the same file;
3. peak memory (max RSS) of ``claravid-dsp`` with one worker on one image, and of the official
   formulation on the same image, each in a fresh subprocess.
Targets: kernel >= 20x faster, per-file <= 1.8x decode, claravid-dsp <= 300 MB; the C
histogram is kept only while it is >= 2x the OpenCV + numpy path.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from claravid.dsp import delentropy, image_complexity, metrics

OFFICIAL = """
import sys, cv2, numpy as np
img = cv2.GaussianBlur(cv2.imread(sys.argv[1], cv2.IMREAD_GRAYSCALE), (3, 3), 1.0)
fx = cv2.Sobel(img.astype(np.int16), ddepth=-1, dx=1, dy=0, ksize=3).astype(int)
fy = cv2.Sobel(img.astype(np.int16), ddepth=-1, dx=0, dy=1, ksize=3).astype(int)
h, _, _ = np.histogram2d(fx.flatten(), fy.flatten(), bins=511, range=[[-256, 256], [-256, 256]])
d = (h / h.sum()).T
nz = d > 0
print(-0.5 * np.sum(d[nz] * np.log2(d[nz])))
"""


def official_delentropy(img: np.ndarray) -> float:
    """The official algorithm: int64 Sobel copies and np.histogram2d."""
    fx = cv2.Sobel(img.astype(np.int16), ddepth=-1, dx=1, dy=0, ksize=3).astype(int)
    fy = cv2.Sobel(img.astype(np.int16), ddepth=-1, dx=0, dy=1, ksize=3).astype(int)
    h, _, _ = np.histogram2d(fx.flatten(), fy.flatten(), bins=511, range=[[-256, 256]] * 2)
    d = (h / h.sum()).T
    nz = d > 0
    return float(-0.5 * np.sum(d[nz] * np.log2(d[nz])))


def make_jpeg(path: Path, seed: int, height: int = 3024, width: int = 4032) -> None:
    """Multi-scale noise, hard-edged shapes, lines and sensor noise: a busy aerial-like frame."""
    rng = np.random.default_rng(seed)
    img = np.full((height, width, 3), 128, np.float32)
    for scale in (3, 12, 48, 192):
        noise = rng.standard_normal((height // scale + 2, width // scale + 2, 3)).astype(np.float32)
        img += cv2.resize(noise, (width, height), interpolation=cv2.INTER_CUBIC) * 60 / scale**0.5
    for _ in range(400):
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        w, h = (int(v) for v in rng.integers(10, 300, 2))
        cv2.rectangle(img, (x, y), (x + w, y + h), colour, -1)
        cv2.line(img, (x, y), (x + 3 * h, y - 2 * w), colour, int(rng.integers(1, 6)))
    img += rng.normal(0, 5, img.shape).astype(np.float32)
    cv2.imwrite(str(path), np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])


def histogram_times(blurred: np.ndarray, repeats: int) -> tuple[float, float]:
    """Best times (s) of the deldensity histogram of one image's gradients: C, OpenCV + numpy."""
    native = metrics._native
    if native is None:
        raise SystemExit("claravid.dsp._deldensity is not built: reinstall with a C compiler")
    gx, gy = cv2.spatialGradient(blurred, ksize=3)

    def with_c() -> np.ndarray:
        counts = np.zeros((512, 512), np.uint32)
        native.count(gx, gy, metrics._BIN_LUT_U16, counts)
        return counts[:511, :511].astype(np.int64)

    assert np.array_equal(with_c(), metrics._counts_opencv(gx, gy))
    return best_of(with_c, repeats), best_of(lambda: metrics._counts_opencv(gx, gy), repeats)


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


# A tiny launcher: ru_maxrss survives fork + exec, so the child must be forked from a small process.
_LAUNCH = """
import resource, subprocess, sys
subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
"""


def peak_rss_mb(argv: list[str]) -> float:
    """Max RSS (MB) of a fresh process running ``argv``."""
    out = subprocess.run(
        [sys.executable, "-c", _LAUNCH, *argv], check=True, capture_output=True, text=True
    )
    return int(out.stdout.strip()) / 1024  # ru_maxrss is in KiB on Linux


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        paths = [Path(tmp) / f"frame{i}.jpg" for i in range(args.images)]
        for i, p in enumerate(paths):
            make_jpeg(p, seed=i)
        print(f"{len(paths)} textured 4032x3024 JPEGs, q90, {paths[0].stat().st_size / 1e6:.1f} MB")

        k_ours, k_off, f_ours, f_dec, h_c, h_cv = [], [], [], [], [], []
        for p in paths:
            blurred = cv2.GaussianBlur(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (3, 3), 1.0)
            ours, off = delentropy(blurred), official_delentropy(blurred)
            assert abs(ours - off) <= 1e-9, (ours, off)
            k_ours.append(best_of(lambda b=blurred: delentropy(b), args.repeats))
            k_off.append(best_of(lambda b=blurred: official_delentropy(b), 2))
            c_time, cv_time = histogram_times(blurred, args.repeats)
            h_c.append(c_time)
            h_cv.append(cv_time)
            f_dec.append(
                best_of(lambda p=p: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), args.repeats)
            )
            f_ours.append(best_of(lambda p=p: image_complexity(p), args.repeats))
            diff = abs(ours - off)
            print(f"  {p.name}: delentropy {ours:.12f}, official {off:.12f}, |diff| {diff:.1e}")
        ko, kf = np.median(k_ours), np.median(k_off)
        print(
            f"kernel   : ours {ko * 1e3:7.1f} ms  official {kf * 1e3:7.1f} ms"
            f"  -> {kf / ko:5.1f}x faster (target >= 20x)"
        )
        hc, hcv = np.median(h_c), np.median(h_cv)
        print(
            f"histogram: C {hc * 1e3:7.1f} ms  OpenCV + numpy {hcv * 1e3:7.1f} ms"
            f"  -> {hcv / hc:5.2f}x (the C extension stays at >= 2x)"
        )
        fo, fd = np.median(f_ours), np.median(f_dec)
        print(
            f"per file : ours {fo * 1e3:7.1f} ms  bare decode {fd * 1e3:7.1f} ms"
            f"  -> {fo / fd:5.2f}x decode (target <= 1.8x)"
        )

        listing = Path(tmp) / "one.txt"
        listing.write_text(str(paths[0]) + "\n")
        cli = [
            sys.executable,
            "-m",
            "claravid.dsp.cli",
            "--data",
            str(listing),
            "--workers",
            "1",
            "--no-cache",
            "--no-progress",
            "--output",
            str(Path(tmp) / "out.json"),
        ]
        ours_mb = peak_rss_mb(cli)
        off_mb = peak_rss_mb([sys.executable, "-c", OFFICIAL, str(paths[0])])
        print(
            f"peak RSS : claravid-dsp {ours_mb:6.0f} MB  official {off_mb:6.0f} MB"
            " (target <= 300 MB)"
        )


if __name__ == "__main__":
    main()

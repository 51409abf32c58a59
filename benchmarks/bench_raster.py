"""Streamed raster prediction: peak memory on a 20,000² GeoTIFF, overhead, COG validity; one run.

    PYTHONPATH=. python benchmarks/bench_raster.py [--side 20000] [--fits 3000] [--window 630]

Makes, in a temp folder, a tiny random-init segmenter (one ViT block, linear head) and generated
RGB GeoTIFFs (smooth texture, tiled, deflate), then prints:
1. memory: ``predict_raster`` on a ``--side``² raster in a fresh subprocess, its peak RSS
   (``ru_maxrss``), against the bytes the in-memory path would need for the logits alone;
2. overhead: on a ``--fits``² raster, the whole streamed prediction (read, windows, blend,
   class map, write the COG) against ``sliding_window_logits`` + argmax on the same pixels held
   in memory, the same windows, in this process, best of ``--repeats``;
3. the big output checked as a COG through GDAL (layout, tiles, overviews, georeference,
   palette, nodata).
Targets: peak RSS <= 1.5 GB; streamed <= 1.15x in-memory.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

CHILD = """
import json, resource, sys, torch
from claravid import models
from claravid.eval.inference.raster_job import predict_raster
from claravid.eval.inference.windows import WindowConfig
torch.set_num_threads(int(sys.argv[5]))
model = models.load_checkpoint(sys.argv[1]).eval()
side = int(sys.argv[4])
colors = [[i * 30, 255 - i * 30, 128] for i in range(model.num_classes)]
result = predict_raster(model, sys.argv[2], sys.argv[3], WindowConfig(size=side, batch_size=4),
                        __import__("numpy").array(colors, "uint8"), confidence=True,
                        progress=False)
print(json.dumps({"peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
                  "seconds": result.seconds, "windows": result.windows}))
"""


def make_raster(path: Path, side: int, seed: int = 0) -> None:
    """A ``side``² RGB GeoTIFF (UTM, 5 cm), written a row of tiles at a time."""
    import cv2
    import rasterio
    from rasterio.transform import from_origin
    from rasterio.windows import Window

    rng = np.random.default_rng(seed)
    profile = {"driver": "GTiff", "width": side, "height": side, "count": 3, "dtype": "uint8",
               "crs": "EPSG:32633", "transform": from_origin(500000, 4000000, 0.05, 0.05),
               "tiled": True, "blockxsize": 512, "blockysize": 512, "compress": "deflate",
               "BIGTIFF": "IF_SAFER"}  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        for top in range(0, side, 512):
            rows = min(512, side - top)
            coarse = rng.integers(0, 256, (rows // 32 + 2, side // 32 + 2, 3), dtype=np.uint8)
            band = cv2.resize(coarse, (side, rows), interpolation=cv2.INTER_LINEAR)
            dst.write(band.transpose(2, 0, 1), window=Window(0, top, side, rows))


def check_cog(path: Path, source: Path) -> list[str]:
    """What GDAL says is wrong with ``path`` as a COG of ``source``'s grid (empty: nothing)."""
    import rasterio

    problems = []
    with rasterio.open(path) as out, rasterio.open(source) as src:
        if out.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") != "COG":
            problems.append("GDAL does not report LAYOUT=COG")
        if not out.profile.get("tiled") or out.block_shapes[0] != (512, 512):
            problems.append(f"not tiled 512: {out.block_shapes}")
        if not out.overviews(1):
            problems.append("no overviews")
        if (out.crs, out.transform, out.shape) != (src.crs, src.transform, src.shape):
            problems.append("georeference or size differ from the input")
        if out.nodata != 255 or not out.colormap(1):
            problems.append("no nodata or no colour table")
        if out.profile.get("compress") != "deflate":
            problems.append("not deflate")
    with open(path, "rb") as f:
        head = f.read(400)
    if b"LAYOUT=IFDS_BEFORE_DATA" not in head or b"KNOWN_INCOMPATIBLE_EDITION=NO" not in head:
        problems.append("the COG ghost header (IFDs before data) is missing")
    return problems


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--side", type=int, default=20000, help="side of the big raster")
    p.add_argument("--fits", type=int, default=3000, help="side of the raster held in memory")
    p.add_argument("--window", type=int, default=630, help="window side (a multiple of 14)")
    p.add_argument("--repeats", type=int, default=2)
    # One thread by default: on a shared machine, multi-threaded small ops wait on descheduled
    # threads and the ratio measures the neighbours; pass --threads on a quiet one.
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)

    from claravid import models
    from claravid.eval.inference.raster_job import predict_raster
    from claravid.eval.inference.windows import WindowConfig, sliding_window_logits
    from claravid.io.raster import RasterReader

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        torch.manual_seed(0)
        # A one-block ViT of width 32 and a linear head: the streaming is measured, not a model.
        vit = {"embed_dim": 32, "depth": 1, "num_heads": 2}
        model = models.build_model("dinov2_vits14", 8, backbone_kwargs=vit, head="linear").eval()
        ckpt = models.save_checkpoint(model, folder / "tiny.pt")
        colors = np.array([[i * 30, 255 - i * 30, 128] for i in range(8)], np.uint8)
        config = WindowConfig(size=args.window, batch_size=4)

        # 2. overhead, on a raster that fits.
        small = folder / "small.tif"
        make_raster(small, args.fits, seed=1)
        with RasterReader(small) as r:
            pixels = torch.from_numpy(r.read_rows(0, args.fits))
        memory, streamed = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            with torch.inference_mode():
                labels = sliding_window_logits(model, pixels, config).argmax(0)
            memory.append(time.perf_counter() - start)
            start = time.perf_counter()
            with torch.inference_mode():
                predict_raster(model, small, folder / "small_out.tif", config, colors,
                               progress=False)  # fmt: skip
            streamed.append(time.perf_counter() - start)
        import rasterio

        with rasterio.open(folder / "small_out.tif") as out:
            same = bool(np.array_equal(out.read(1), labels.numpy().astype(np.uint8)))
        ratio = min(streamed) / min(memory)
        print(
            f"overhead on {args.fits}²: streamed {min(streamed):.1f} s vs in-memory "
            f"{min(memory):.1f} s = {ratio:.3f}x (target <= 1.15x); labels equal: {same}"
        )

        # 1. memory, on the big raster, in a fresh process.
        big = folder / "big.tif"
        start = time.perf_counter()
        make_raster(big, args.side)
        print(
            f"generated {args.side}² GeoTIFF ({big.stat().st_size / 1e9:.2f} GB on disk) in "
            f"{time.perf_counter() - start:.0f} s"
        )
        out = folder / "big_out.tif"
        run = subprocess.run([sys.executable, "-c", CHILD, str(ckpt), str(big), str(out),
                              str(args.window), str(args.threads)],
                             capture_output=True, text=True, check=True)  # fmt: skip
        child = json.loads(run.stdout.strip().splitlines()[-1])
        logits_gb = 8 * args.side**2 * 4 / 1e9
        print(
            f"peak RSS on {args.side}²: {child['peak_rss'] / 1e9:.2f} GB (target <= 1.5 GB; the "
            f"in-memory path's logits alone: {logits_gb:.1f} GB); {child['windows']} windows "
            f"in {child['seconds']:.0f} s"
        )

        # 3. the output as a COG.
        problems = check_cog(out, big)
        print(
            "COG: valid (GDAL: LAYOUT=COG, tiled 512, overviews, georeference, palette, nodata)"
            if not problems
            else f"COG problems: {problems}"
        )


if __name__ == "__main__":
    main()

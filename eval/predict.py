"""``claravid-predict``: label maps and colour overlays for unlabeled images (e.g. a real flight).

::

    claravid-predict --checkpoint best.pt flight/ --output flight-pred
    claravid-predict --onnx model.onnx a.jpg b.jpg --output pred --palette uavid --scale 0.5

Writes ``OUT/<name>.png`` (single-channel uint8 train ids: the ``--predictions`` format of
``claravid-eval``) and ``OUT/overlays/<name>.jpg`` (the image blended with palette colours),
where ``<name>`` is the image's path relative to the input folder without its extension (or
its stem, for images listed one by one). Same sliding windows as the evaluation.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from tqdm.auto import tqdm

from claravid import modalities
from claravid.cli import UsageError, add_debug_flag, check_device, check_output_dir, run_cli
from claravid.eval.predictions import MARKER, write_image, write_marker, write_prediction
from claravid.eval.windows import WindowConfig, flag_precision, predict_labels
from claravid.palettes import Palette, load_palette
from claravid.transforms import eval_transforms

PROG = "claravid-predict"
EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
ALPHA = 0.5  # overlay: half image, half class colour


class ImageList(Dataset):
    """Images named by ``keys``; samples ``{"image", "path", "key"}`` through ``transforms``."""

    def __init__(self, paths: list[Path], keys: list[str], transforms: Any) -> None:
        self.paths, self.keys, self.transforms = paths, keys, transforms

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index: int) -> dict[str, Any]:
        path = self.paths[index]
        sample = {
            "image": torch.from_numpy(modalities.read_rgb(path)).permute(2, 0, 1),
            "path": str(path),
            "key": self.keys[index],
        }
        return self.transforms(sample)


def list_images(inputs: list[Path]) -> tuple[list[Path], list[str]]:
    """Image files and their output names from one folder (recursive) or listed files.

    Raises:
        UsageError: nothing found, a missing file, or two images with the same name.
    """
    if len(inputs) == 1 and inputs[0].is_dir():
        root = inputs[0]
        paths = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in EXTENSIONS)
        if not paths:
            raise UsageError(f"no images ({', '.join(EXTENSIONS)}) under {root}")
        keys = [p.relative_to(root).with_suffix("").as_posix() for p in paths]
        return paths, keys
    for p in inputs:
        if not p.exists():
            raise UsageError(f"{p} not found")
        if not p.is_file():
            raise UsageError(f"{p} is not an image file (give one folder or image files)")
    keys = [p.stem for p in inputs]
    if len(set(keys)) < len(keys):
        raise UsageError("two listed images share a file name; give their folder instead")
    return list(inputs), keys


def overlay(image: np.ndarray, ids: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """The RGB image blended with the class colours of ``ids`` (uint8 H×W×3, RGB)."""
    table = np.zeros((256, 3), dtype=np.uint8)
    table[: len(colors)] = colors
    return cv2.addWeighted(image, 1 - ALPHA, table[ids], ALPHA, 0)


def _palette_for(
    args: argparse.Namespace, defaults: dict[str, Any], num_classes: int | None
) -> Palette | None:
    """The palette from ``--palette`` or the checkpoint's config; None when neither says.

    Never guessed from the class count: several palettes share one (UAVid has 8 classes, a
    custom reduction may too), and a guess would colour the overlays with the wrong classes.
    """
    name = args.palette or defaults.get("palette")
    if name is None:
        if not args.no_overlays:
            raise UsageError(
                "the model does not record its palette (an ONNX file or a plain checkpoint): "
                "pass --palette for the overlays, or --no-overlays for label maps only"
            )
        return None
    palette = load_palette(name)
    if num_classes is not None and palette.num_classes != num_classes:
        raise UsageError(
            f"the model predicts {num_classes} classes but palette {palette.name} has "
            f"{palette.num_classes}; pass the palette it was trained with"
        )
    return palette


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-predict`` arguments."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0].strip("`: "))
    p.add_argument("images", nargs="+", type=Path, help="a folder of images, or image files")
    p.add_argument("--checkpoint", type=Path, help="PyTorch checkpoint")
    p.add_argument("--onnx", type=Path, help="ONNX model")
    p.add_argument("--output", "-o", type=Path, required=True, help="output folder")
    p.add_argument("--palette", help="palette for the colours (default: the checkpoint's)")
    p.add_argument("--window", type=int, default=None, help="window size (default 630)")
    p.add_argument("--stride", type=int, default=None, help="window step (default 2/3 window)")
    p.add_argument("--scale", type=float, default=1.0, help="resize images first")
    p.add_argument("--batch-size", type=int, default=4, help="windows per forward pass")
    p.add_argument("--device", help="cpu or cuda (default: cuda when available)")
    p.add_argument(
        "--precision", help="PyTorch model: fp32 or bf16 (default: fp32 on CPU, bf16/fp16 on CUDA)"
    )
    p.add_argument("--workers", type=int, default=0, help="image decoding processes")
    p.add_argument("--no-overlays", action="store_true", help="label maps only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true", help="replace a foreign output folder")
    add_debug_flag(p)
    return p


def run(args: argparse.Namespace) -> int:
    """Predict every image and write its label map and overlay."""
    from claravid.eval.sources import load_source

    if (args.checkpoint is None) == (args.onnx is None):
        raise UsageError("give exactly one of --checkpoint and --onnx")
    precision = flag_precision(args.precision, pytorch=args.checkpoint is not None)
    out = check_output_dir(args.output, marker=MARKER, overwrite=args.overwrite)
    paths, keys = list_images(args.images)
    check_device(args.device)  # one line, not CUDA's traceback
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    source = load_source(args.checkpoint, args.onnx, device=device)
    palette = _palette_for(args, source.defaults, source.num_classes)
    fixed = getattr(source.model, "input_size", None)
    size = (args.window, args.window) if args.window else (fixed or (630, 630))
    config = WindowConfig(
        size=size,
        stride=None if args.stride is None else (args.stride, args.stride),
        scale=args.scale,
        batch_size=args.batch_size,
        precision=precision,
    )
    if source.patch_size:
        config.check_patch(source.patch_size)
    loader = DataLoader(
        ImageList(paths, keys, eval_transforms()), batch_size=None, num_workers=args.workers
    )
    bar = tqdm(loader, total=len(paths), desc="predict", unit="img", disable=args.no_progress)
    for sample in bar:
        ids = predict_labels(source.model, sample["image"].to(device), config)
        ids = ids.to("cpu", torch.uint8).numpy()
        write_prediction(out, sample["key"], ids)
        if not args.no_overlays:
            rgb = modalities.read_rgb(sample["path"])
            blend = cv2.cvtColor(overlay(rgb, ids, palette.colors), cv2.COLOR_RGB2BGR)  # type: ignore[union-attr]
            target = out / "overlays" / f"{sample['key']}.jpg"
            write_image(target, blend, [cv2.IMWRITE_JPEG_QUALITY, 90])
    write_marker(out, palette, {"kind": source.kind, "path": source.path}, images=len(paths))
    print(f"{len(paths)} label maps: {out}/<name>.png" + ("" if args.no_overlays else
          f"; overlays: {out / 'overlays'}"))  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    """``claravid-predict``."""
    return run_cli(PROG, run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

"""``claravid-predict``: label maps and colour overlays for unlabeled images (e.g. a real flight).

::

    claravid-predict --checkpoint best.pt flight/ --output flight-pred
    claravid-predict --onnx model.onnx a.jpg b.jpg --output pred --palette uavid --scale 0.5

Window, stride, scale, batch size, palette and normalisation are decided as in
``claravid-eval`` (`claravid.eval.inference.sources.resolve_settings`): the flag, else what the
checkpoint's training config or the ONNX file's metadata records, else the default; so the
label maps equal the ones ``claravid-eval --save-predictions`` writes for the same model.

Writes ``OUT/<name>.png`` (single-channel uint8 train ids: the ``--predictions`` format of
``claravid-eval``) and ``OUT/overlays/<name>.jpg`` (the image blended with palette colours),
where ``<name>`` is the image's path relative to the input folder without its extension (or
its stem, for images listed one by one). Same sliding windows as the evaluation.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset
from tqdm.auto import tqdm

from claravid.data.palettes import Palette, load_palette
from claravid.eval.cli.raster_predict import (
    add_raster_flags,
    check_raster_flags,
    check_rasters,
    run_rasters,
)
from claravid.eval.inference.augment import tta_from_flags
from claravid.eval.inference.sources import RunSettings
from claravid.eval.inference.windows import predict_labels
from claravid.eval.inputs.label_maps import (
    MARKER,
    image_key,
    write_image,
    write_marker,
    write_prediction,
)
from claravid.infra.cli import (
    UsageError,
    add_checkpoint_flag,
    add_debug_flag,
    add_device_flag,
    add_output_flag,
    add_precision_flag,
    add_progress_flag,
    add_statistics_flag,
    add_tta_flags,
    add_window_flags,
    add_workers_flag,
    check_device,
    run_cli,
)
from claravid.infra.files import check_output_dir
from claravid.infra.precision import flag_precision
from claravid.io import modalities
from claravid.models.backbones.specs import NAMED_STATISTICS
from claravid.models.export.runtime import PROVIDERS

PROG = "claravid-predict"
EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
ALPHA = 0.5  # overlay: half image, half class colour


class ImageList(Dataset):
    """Images named by ``keys``: samples ``{"image": uint8 [3,H,W], "path", "key"}`` (normalised
    on the model's device by the sliding windows)."""

    def __init__(self, paths: list[Path], keys: list[str]) -> None:
        self.paths, self.keys = paths, keys

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index: int) -> dict[str, Any]:
        path = self.paths[index]
        return {
            "image": torch.from_numpy(modalities.read_rgb(path)).permute(2, 0, 1),
            "path": str(path),
            "key": self.keys[index],
        }


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
        keys = [image_key(p, root) for p in paths]
        return paths, keys
    for p in inputs:
        if not p.exists():
            raise UsageError(f"{p} not found")
        if not p.is_file():
            raise UsageError(f"{p} is not an image file (give one folder or image files)")
    keys = [image_key(p) for p in inputs]
    if len(set(keys)) < len(keys):
        raise UsageError("two listed images share a file name; give their folder instead")
    return list(inputs), keys


def overlay(image: np.ndarray, ids: np.ndarray, colors: np.ndarray) -> np.ndarray:
    """The RGB image blended with the class colours of ``ids`` (uint8 H×W×3, RGB)."""
    table = np.zeros((256, 3), dtype=np.uint8)
    table[: len(colors)] = colors
    return cv2.addWeighted(image, 1 - ALPHA, table[ids], ALPHA, 0)


def _palette_for(
    settings: RunSettings, no_overlays: bool, num_classes: int | None
) -> Palette | SimpleNamespace | None:
    """The palette of the resolved settings: a name or YAML, or the one an ONNX file carries
    (names and colours, no reduction needed to colour overlays); None when nothing says.

    Never guessed from the class count: several palettes share one (UAVid has 8 classes, a
    custom reduction may too), and a guess would colour the overlays with the wrong classes.
    """
    info = settings.palette_info
    if info is not None:  # the ONNX file's own record: no palette file needed
        palette: Any = SimpleNamespace(
            name=info["name"],
            names=tuple(info["names"]),
            colors=np.asarray(info["colors"], dtype=np.uint8).reshape(-1, 3),
            num_classes=len(info["names"]),
        )
    elif settings.palette is not None:
        palette = load_palette(settings.palette)
    else:
        if not no_overlays:
            raise UsageError(
                "the model does not record its palette (a foreign ONNX file or a plain "
                "checkpoint): pass --palette for the overlays, or --no-overlays for label maps only"
            )
        return None
    if num_classes is not None and palette.num_classes != num_classes:
        raise UsageError(
            f"the model predicts {num_classes} classes but palette {palette.name} has "
            f"{palette.num_classes}; pass the palette it was trained with"
        )
    return palette


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-predict`` arguments."""
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Label maps and colour overlays for unlabeled images (e.g. a real flight), "
        "written into the -o/--output folder; the model is --checkpoint or --onnx.",
    )
    p.add_argument("images", nargs="+", type=Path, help="a folder of images, or image files")
    add_checkpoint_flag(p)
    p.add_argument("--onnx", type=Path, help="ONNX model")
    add_output_flag(p, required=True)
    p.add_argument("--palette", help="palette for the colours (default: the checkpoint's)")
    add_window_flags(p)
    add_tta_flags(p)
    add_statistics_flag(p, NAMED_STATISTICS)
    add_device_flag(p)
    add_precision_flag(p)
    p.add_argument("--provider", choices=PROVIDERS, help="ONNX Runtime provider (--onnx)")
    add_workers_flag(p, "image decoding")
    p.add_argument("--no-overlays", action="store_true", help="label maps only")
    add_raster_flags(p)
    add_progress_flag(p)
    p.add_argument("--overwrite", action="store_true", help="replace a foreign output folder")
    add_debug_flag(p)
    return p


def run(args: argparse.Namespace) -> int:
    """Predict every image and write its label map and overlay."""
    if (args.checkpoint is None) == (args.onnx is None):
        raise UsageError("give exactly one of --checkpoint and --onnx")
    precision = flag_precision(args.precision, pytorch=args.checkpoint is not None)
    check_raster_flags(args)
    if args.raster and args.gsd is not None and args.scale is not None:
        raise UsageError(
            "give --gsd or --scale, not both (--gsd sets the scale to match the model)"
        )
    out = check_output_dir(args.output, marker=MARKER, overwrite=args.overwrite)
    if args.raster:
        return _run_rasters(args, out, precision)
    paths, keys = list_images(args.images)
    tta = tta_from_flags(args.tta, args.tta_scales, args.flip, args.tta_size)
    device, source, settings = _model_and_settings(args, precision, gsd=args.gsd, tta=tta)
    palette = _palette_for(settings, args.no_overlays, source.num_classes)
    config = settings.window
    loader = DataLoader(ImageList(paths, keys), batch_size=None, num_workers=args.workers)
    bar = tqdm(loader, total=len(paths), desc="predict", unit="img", disable=args.no_progress)
    for sample in bar:
        pred = predict_labels(source.model, sample["image"].to(device), config)
        ids = pred.to("cpu", torch.uint8).numpy()
        write_prediction(out, sample["key"], ids)
        if not args.no_overlays:
            rgb = sample["image"].permute(1, 2, 0).numpy()  # the decoded pixels, not a re-read
            # Overlays are refused without a palette.
            blend = cv2.cvtColor(overlay(rgb, ids, palette.colors), cv2.COLOR_RGB2BGR)  # type: ignore[union-attr]
            target = out / "overlays" / f"{sample['key']}.jpg"
            write_image(target, blend, [cv2.IMWRITE_JPEG_QUALITY, 90])
    described = {**source.describe(), "settings": settings.describe()}
    # An ONNX file's palette: its names and colours.
    write_marker(out, palette, described, images=len(paths))  # type: ignore[arg-type]
    print(f"{len(paths)} label maps: {out}/<name>.png" + ("" if args.no_overlays else
          f"; overlays: {out / 'overlays'}"))  # fmt: skip
    return 0


def _model_and_settings(
    args: argparse.Namespace, precision: str, **choices: Any
) -> tuple[torch.device, Any, Any]:
    """The device, the model and its run settings: the same decision as claravid-eval's (flags,
    else the model file's record, else defaults); ``choices`` adds ``gsd`` and ``tta``."""
    from claravid.eval.inference.sources import load_source, resolve_settings

    check_device(args.device)  # one line, not CUDA's traceback
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    source = load_source(args.checkpoint, args.onnx, device=device, provider=args.provider)
    settings = resolve_settings(
        source, window=args.window, stride=args.stride, scale=args.scale,
        batch_size=args.batch_size, palette=args.palette, precision=precision,
        statistics=args.statistics, **choices,
    )  # fmt: skip
    return device, source, settings


def _run_rasters(args: argparse.Namespace, out: Path, precision: str) -> int:
    """``--raster``: every input streamed into ``OUT/<name>.tif`` (a COG class map)."""
    rasters = check_rasters(args)  # each raster's problem in one line, before loading the model
    # One copy per window (a protocol a checkpoint records is not streamed); --gsd is the
    # raster's own, resolved by run_rasters.
    _, source, settings = _model_and_settings(args, precision, tta=False)
    palette = _palette_for(settings, True, source.num_classes)
    if palette is None:
        raise UsageError(
            "the model does not record its palette: pass --palette for the class map's colours"
        )
    results = run_rasters(args, rasters, source, settings, palette.colors, out)
    described = {**source.describe(), "settings": settings.describe()}
    write_marker(out, palette, described, images=len(results))  # type: ignore[arg-type]
    for r in results:
        gsd = "" if r.raster_gsd is None else f", GSD {r.raster_gsd[0]:.4g} m/px"
        print(f"{r.path}: {r.width}x{r.height}{gsd}, {r.windows} windows in {r.seconds:.0f} s")
    print(f"{len(results)} class map{'s' * (len(results) != 1)} (COG): {out}/<name>.tif")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``claravid-predict``."""
    return run_cli(PROG, run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

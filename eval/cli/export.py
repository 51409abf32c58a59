"""The ``claravid-export`` console script: parses, exports (`claravid.models.export.onnx`), prints.

    claravid-export --checkpoint runs/exp/best.pt --output model.onnx --size 630x630
    claravid-export --checkpoint runs/exp/best.pt --output model-int8.onnx --dtype int8

The export itself lives in ``models/``, which never imports the data layer; but the file it
writes should carry the palette's class names and colours (not only its name) and, for static
int8 quantisation, be calibrated on real images. Both need the data layer, so the console
script lives here, downstream of both.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from claravid.infra.cli import (
    EXIT_FAILED,
    UsageError,
    add_checkpoint_flag,
    add_debug_flag,
    add_output_flag,
    add_progress_flag,
    parse_size,
    positive_float,
    positive_int,
    run_cli,
)
from claravid.infra.files import check_output_file
from claravid.models.export.metadata import DTYPES, KEY, PREFIX, normalisation_from_config
from claravid.models.export.onnx import (
    ExportCheckError,
    ExportSettings,
    Provenance,
    export_onnx,
)
from claravid.models.grid import natural_size, patch_fix

PROG = "claravid-export"


def palette_info(name: str) -> dict[str, Any] | None:
    """The palette a checkpoint names, as plain data for the ONNX metadata (None: unreadable)."""
    from claravid.data.palettes import load_palette

    try:
        palette = load_palette(name)
    except (OSError, ValueError) as exc:
        warnings.warn(f"the ONNX file will not carry the palette: {exc}", UserWarning, stacklevel=2)
        return None
    return {
        "name": palette.name,
        "names": list(palette.names),
        "colors": palette.colors.tolist(),
        "ignore_index": int(palette.ignore_index),
    }


def calibration_batches(
    folder: str | Path,
    count: int,
    size: tuple[int, int],
    normalisation: dict[str, Any],
    seed: int = 0,
) -> Iterator[np.ndarray]:
    """``count`` random crops of ``size`` from the images under ``folder``, one per batch.

    A ClaraVid root gives its RGB frames (``left_rgb``) only, not the label images. Images are
    taken in a seeded random order, cycling when there are fewer images than crops; an image
    smaller than the crop is padded with the mean colour (0 after normalisation).
    """
    from claravid.eval.cli.predict import list_images
    from claravid.io import modalities

    paths, _ = list_images([Path(folder)])
    rgb = [p for p in paths if "left_rgb" in p.parts]
    paths = rgb or paths
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(paths))
    mean = np.asarray(normalisation["mean"], np.float32).reshape(3, 1, 1)
    std = np.asarray(normalisation["std"], np.float32).reshape(3, 1, 1)
    h, w = size
    for i in range(count):
        image = modalities.read_rgb(paths[order[i % len(paths)]])
        y = int(rng.integers(0, max(1, image.shape[0] - h + 1)))
        x = int(rng.integers(0, max(1, image.shape[1] - w + 1)))
        crop = image[y : y + h, x : x + w].transpose(2, 0, 1).astype(np.float32)
        out = np.zeros((1, 3, h, w), np.float32)
        out[0, :, : crop.shape[1], : crop.shape[2]] = (crop / 255 - mean) / std
        yield out


def fraction(text: str) -> float:
    """argparse type: a number in [0, 1]."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1], got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-export`` argument parser."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Export a claravid segmenter checkpoint to ONNX, checked with ONNX Runtime, "
        "into the -o/--output .onnx file, in the number format --dtype names.",
        epilog="Exit status: 0 ok; 1 the export differs from PyTorch beyond --tolerance or "
        "--min-agreement (nothing written); 2 a bad argument, an unreadable checkpoint or an "
        "unusable --output.",
    )
    add_checkpoint_flag(parser, required=True)
    add_output_flag(parser, metavar="FILE", required=True)
    parser.add_argument("--size", type=parse_size, metavar="WxH",
                        help="input size, width x height or N for N x N, patch multiples "
                        "(default: the model's natural size, 630 for patches of 14, 640 for "
                        "16)")  # fmt: skip
    parser.add_argument("--dynamic", action="store_true", help="dynamic height and width")
    parser.add_argument("--dtype", choices=DTYPES, default="fp32",
                        help="the file's number format: fp32 (default), fp16 (GPUs) or int8 "
                        "(CPUs)")  # fmt: skip
    parser.add_argument("--no-check", action="store_true", help="skip the ONNX Runtime check")
    parser.add_argument("--tolerance", type=positive_float, default=None,
                        help="max allowed abs difference of logits (default 1e-3 for fp32, "
                        "0.05 for fp16, not checked for int8)")  # fmt: skip
    parser.add_argument("--min-agreement", type=fraction, default=None,
                        help="min fraction of pixels with PyTorch's argmax (default 0.97 for "
                        "int8, not checked otherwise)")  # fmt: skip
    parser.add_argument("--calibration", metavar="DATA",
                        help="int8: static QDQ quantisation calibrated on crops of these images "
                        "(a dataset root or an image folder); default dynamic")  # fmt: skip
    parser.add_argument("--calibration-images", type=positive_int, metavar="N",
                        help="int8: number of calibration crops (default 64)")  # fmt: skip
    parser.add_argument("--per-channel", action="store_true",
                        help="int8: one weight scale per output channel")  # fmt: skip
    parser.add_argument(
        "--overwrite", action="store_true", help="replace an --output claravid-export did not write"
    )
    add_progress_flag(parser, help="print only the file written, not the check's numbers")
    add_debug_flag(parser)
    return parser


def _exported(path: str | os.PathLike) -> bool:
    """Whether ``path`` is an ONNX file claravid-export wrote (ours to replace)."""
    if not Path(path).is_file():
        return False
    try:
        import onnx

        proto = onnx.load(str(path), load_external_data=False)
    except Exception:  # not ONNX at all: someone else's file
        return False
    return any(p.key == KEY or p.key.startswith(PREFIX) for p in proto.metadata_props)


def input_size(size: tuple[int, int] | None, patch_size: int) -> tuple[int, int]:
    """``(width, height)`` from ``--size WxH``; unset, the model's natural size (630 for patches
    of 14, 640 for patches of 16).

    Raises:
        UsageError: a size that is not a multiple of ``patch_size`` (naming the two nearest that
            are).
    """
    if size is not None:
        width, height = size
    else:
        width = height = natural_size(patch_size)
    if width % patch_size or height % patch_size:  # said in --size terms, not as a tensor shape
        raise UsageError(
            f"input size {width}x{height} (WxH) is not a multiple of the model's patch size "
            f"{patch_size}: {patch_fix(height, width, patch_size, '--size ')}"
        )
    return width, height


def _run(args: argparse.Namespace) -> int:
    from claravid.models.checkpoint import model_from_checkpoint, read_checkpoint

    checkpoint = Path(args.checkpoint)
    output = check_output_file(args.output, what="--output")
    if output.suffix.lower() != ".onnx":
        # A typo here (the checkpoint's own name, an image) would replace a file of another kind.
        raise UsageError(f"--output {output} must end in .onnx")
    # Our own earlier export may be replaced; anyone else's file only with --overwrite.
    check_output_file(output, overwrite=args.overwrite or _exported(output), what="--output")
    if args.dtype != "int8" and (args.calibration is not None or args.per_channel):
        raise UsageError("--calibration and --per-channel apply to --dtype int8 only")
    if args.calibration_images is not None and args.calibration is None:
        raise UsageError("--calibration-images does nothing without --calibration DATA; drop it")
    if args.calibration is not None and not Path(args.calibration).is_dir():
        raise UsageError(f"--calibration {args.calibration} is not a folder of images")
    if output.exists() and checkpoint.exists() and output.samefile(checkpoint):
        raise UsageError(f"--output {output} is the checkpoint itself; choose another file")
    ckpt = read_checkpoint(checkpoint)
    model = model_from_checkpoint(ckpt, checkpoint)
    width, height = input_size(args.size, model.patch_size)
    config = ckpt.get("config") if isinstance(ckpt.get("config"), dict) else None
    step = ckpt.get("step") if isinstance(ckpt.get("step"), int) else None
    gsd = ckpt.get("gsd") if isinstance(ckpt.get("gsd"), dict) else None
    del ckpt
    palette = None
    data = config.get("data") if config else None
    name = data.get("palette") if isinstance(data, dict) else None
    if isinstance(name, str):
        palette = palette_info(name)
    calibration = None
    if args.calibration is not None:
        # The statistics the file will record: the config's, else the backbone's.
        normalisation = normalisation_from_config(config, (model.mean, model.std))
        size = (height, width)
        calibration = calibration_batches(
            args.calibration, args.calibration_images or 64, size, normalisation
        )
    try:
        settings = ExportSettings(
            height=height,
            width=width,
            dynamic=args.dynamic,
            dtype=args.dtype,
            check=not args.no_check,
            tolerance=args.tolerance,
            min_agreement=args.min_agreement,
            per_channel=args.per_channel,
        )
        record = Provenance(config=config, step=step, palette=palette, gsd=gsd)
        result = export_onnx(model, output, settings, provenance=record, calibration=calibration)
    except ExportCheckError as exc:
        print(f"{PROG}: error: {exc}; nothing was written", file=sys.stderr)
        return EXIT_FAILED
    if result["check_shape"] is not None and not args.no_progress:
        print(
            f"onnxruntime vs PyTorch on input {list(result['check_shape'])}: max abs diff of "
            f"logits {result['max_abs_diff']:.3g}, argmax agreement "
            f"{100 * result['agreement']:.2f} %"
        )
    print(f"wrote {result['path']} ({args.dtype})")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``claravid-export --checkpoint CKPT --output model.onnx [--size WxH | --dynamic]``."""
    return run_cli(PROG, _run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

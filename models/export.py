"""ONNX export of a segmenter, with checks, and the ``claravid-export`` command.

We use the dynamo exporter (``torch.onnx.export(..., dynamo=True)``, the default in torch 2.9+,
through onnxscript): it handles SDPA, bicubic and symbolic H/W. The batch is always dynamic; the
example batch is 2 because a batch of 1 lets the exporter freeze that dimension.

    claravid-export --checkpoint runs/exp/best.pt --output model.onnx --size 630x630
    claravid-export --checkpoint runs/exp/best.pt --output model-int8.onnx --precision int8

(``claravid-export CHECKPOINT ...`` and ``--height H --width W``, the older spellings, still
work.)

The file carries what it takes to run the model as evaluated (`claravid.models.onnx_metadata`).
The palette's colours come from the data layer, which ``models/`` never imports: the console
script (``claravid.eval.export_cli``) passes a resolver into :func:`main`.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import shutil
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from claravid.cli import (
    EXIT_FAILED,
    UsageError,
    add_debug_flag,
    check_output_file,
    given_once,
    parse_size,
    positive_float,
    positive_int,
    run_cli,
)
from claravid.models.onnx_metadata import (
    KEY,
    PRECISIONS,
    PREFIX,
    build_metadata,
    metadata_props,
    normalisation_from_config,
)
from claravid.models.onnx_runtime import OnnxSegmenter
from claravid.models.segmenter import Segmenter

# Opset 23 has a fused Attention op (SDPA maps to it; onnxruntime runs it without materialising
# the N x N score matrix in memory-bound MatMul/Softmax pairs).
OPSET = 23
#: Largest max-abs logit difference accepted by default (int8 is judged by its agreement).
DEFAULT_TOLERANCE: dict[str, float | None] = {"fp32": 1e-3, "fp16": 5e-2, "int8": None}
DEFAULT_MIN_AGREEMENT = 0.97  # int8: fraction of pixels whose argmax equals PyTorch's
DEFAULT_SIZE = 630  # input height and width of a fixed-size export (the paper's window)


class ExportCheckError(RuntimeError):
    """The exported graph's outputs differ from PyTorch's beyond the tolerance."""


@contextmanager
def _export_mode(model: Segmenter, size: tuple[int, int] | None):
    """Eval mode, and for a fixed size a stored positional embedding; restored afterwards."""
    was_training = model.training
    model.eval()
    if size is not None:
        model.backbone.freeze_pos_embed(*size)
    # The exporter warns about every torchvision op it cannot register; torchvision is unused.
    registration = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registration.level
    registration.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            # torch's own exporter internals use a deprecated pytree API (not our code).
            warnings.filterwarnings("ignore", message=".*LeafSpec", category=FutureWarning)
            yield
    finally:
        registration.setLevel(level)
        model.backbone.freeze_pos_embed(None)
        model.train(was_training)


def export_onnx(
    model: Segmenter,
    path: str | os.PathLike,
    height: int = 630,
    width: int = 630,
    dynamic: bool = False,
    check: bool = True,
    tolerance: float | None = None,
    *,
    precision: str = "fp32",
    min_agreement: float | None = None,
    config: dict[str, Any] | None = None,
    step: int | None = None,
    palette: dict[str, Any] | None = None,
    calibration: Iterable[np.ndarray] | None = None,
    per_channel: bool = False,
) -> dict[str, Any]:
    """Export ``model`` to ONNX, then check it with ``onnx.checker`` and ONNX Runtime.

    The file carries the ``claravid`` metadata document (`claravid.models.onnx_metadata`):
    what it takes to run the model as it was evaluated.

    Args:
        model: A `Segmenter`.
        path: Output ``.onnx`` (large models also write ``<path>.data`` next to it), written
            atomically: only a complete (and, with ``check``, checked) export replaces it.
        height: Example (and, unless dynamic, the only) input height; a patch multiple.
        width: Example input width.
        dynamic: Also make H and W dynamic (multiples of the patch size).
        check: Run the checks below after export.
        tolerance: Largest allowed max-abs difference of logits between ORT and PyTorch
            (default 1e-3 for fp32, 0.05 for fp16; int8 is judged by ``min_agreement``).
        precision: ``fp32``, ``fp16`` (float16 graph, float32 input and output) or ``int8``
            (`claravid.models.quantize`).
        min_agreement: Smallest allowed fraction of pixels whose argmax equals PyTorch's
            (default 0.97 for int8, not checked otherwise).
        config: The checkpoint's resolved training config (windows, normalisation, hash).
        step: The training step of the checkpoint.
        palette: ``{"name", "names", "colors", "ignore_index"}`` as plain lists.
        calibration: int8 only: batches of normalised images for static QDQ quantisation.
        per_channel: int8 only: one weight scale per output channel.

    Returns:
        ``{"path", "max_abs_diff", "agreement", "check_shape", "precision", ...}`` (the
        check's entries None when not checked).

    Raises:
        ValueError: a size that is not a positive multiple of the patch size, or a tolerance,
            agreement or precision out of range.
        ExportCheckError: ORT's logits differ from PyTorch's beyond ``tolerance`` or
            ``min_agreement`` (nothing is written then).
    """
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if tolerance is None:
        tolerance = DEFAULT_TOLERANCE[precision]
    if min_agreement is None and precision == "int8":
        min_agreement = DEFAULT_MIN_AGREEMENT
    _check_settings(model, height, width, tolerance)
    if min_agreement is not None and not (
        isinstance(min_agreement, (int, float)) and 0 <= min_agreement <= 1
    ):
        raise ValueError(f"min_agreement must be a fraction in [0, 1], got {min_agreement!r}")
    if precision != "int8" and (calibration is not None or per_channel):
        raise ValueError("calibration and per_channel apply to int8 exports only")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Written in a temp folder beside the target and moved into place once written (and checked):
    # an interrupted or failed export never leaves half a file, nor replaces a good one. The
    # folder keeps the final file name, which external weights (<name>.data) reference.
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        staged = staging / path.name
        result: dict[str, Any] = {"path": path, "precision": precision}
        if precision == "fp32":
            _export(model, staged, height, width, dynamic)
        else:
            (staging / "fp32").mkdir()
            plain = staging / "fp32" / path.name
            _export(model, plain, height, width, dynamic)
            if precision == "fp16":
                from claravid.models.onnx_fp16 import convert_to_fp16

                result["conversion"] = convert_to_fp16(str(plain), str(staged))
            else:
                from claravid.models.quantize import quantize_int8

                result["conversion"] = quantize_int8(
                    plain, staged, calibration=calibration, per_channel=per_channel
                )
            shutil.rmtree(staging / "fp32")
        size = None if dynamic else (height, width)
        document = build_metadata(
            model.model_args,
            patch_size=model.patch_size,
            num_classes=model.num_classes,
            input_size=size,
            precision=precision,
            config=config,
            step=step,
            palette=palette,
        )
        _write_metadata(staged, document)
        result.update(max_abs_diff=None, agreement=None, check_shape=None)
        if check:
            try:
                result.update(
                    check_export(
                        model, staged, height, width, dynamic, tolerance, min_agreement,
                        document["normalisation"],
                    )
                )  # fmt: skip
            except ExportCheckError as exc:  # name the file the user asked for, not the temp one
                raise ExportCheckError(str(exc).replace(str(staged), str(path))) from None
        for item in sorted(staging.iterdir(), key=lambda f: f == staged):  # the .onnx last
            os.replace(item, path.parent / item.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return result


def _check_settings(model: Segmenter, height: object, width: object, tolerance: object) -> None:
    """Reject nonsense sizes and tolerances before the (slow) export."""
    for name, value in (("height", height), ("width", width)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value <= 0:
            raise ValueError(
                f"{name} must be a positive multiple of the patch size {model.patch_size}, "
                f"got {value!r}"
            )
    model.backbone.check_input_size(int(height), int(width))  # type: ignore[arg-type]
    if tolerance is not None and (
        not isinstance(tolerance, (int, float))
        or isinstance(tolerance, bool)
        or not math.isfinite(tolerance)
        or tolerance <= 0
    ):
        raise ValueError(
            f"tolerance must be a finite number > 0 (the largest allowed max-abs difference of "
            f"logits, e.g. 1e-3), got {tolerance!r}"
        )


def _export(model: Segmenter, path: Path, height: int, width: int, dynamic: bool) -> None:
    p = model.patch_size
    param = next(model.parameters())
    example = torch.randn(2, 3, height, width, device=param.device)
    batch = torch.export.Dim("batch", min=1, max=4096)
    shapes: dict[int, Any] = {0: batch}
    if dynamic:
        shapes[2] = p * torch.export.Dim("grid_h", min=1, max=1024)
        shapes[3] = p * torch.export.Dim("grid_w", min=1, max=1024)
    # One self-contained file unless the weights pass protobuf's 2 GB limit (ViT-g).
    external = sum(t.numel() * t.element_size() for t in model.state_dict().values()) > 1.8e9
    with _export_mode(model, None if dynamic else (height, width)):
        torch.onnx.export(
            model,
            (example,),
            str(path),
            input_names=["image"],
            output_names=["logits"],
            dynamic_shapes={"x": shapes},
            dynamo=True,
            external_data=external,
            opset_version=OPSET,
            verbose=False,
        )


def _write_metadata(path: Path, document: dict[str, Any]) -> None:
    import onnx

    proto = onnx.load(str(path), load_external_data=False)
    del proto.metadata_props[:]
    for key, value in metadata_props(document).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))


def smooth_images(
    shape: tuple[int, ...], normalisation: dict[str, Any], seed: int = 0
) -> np.ndarray:
    """Normalised images that look more like photos than noise: smooth colour fields + grain.

    Random coarse colour grids (a few cells per side) upsampled bicubically, plus a little
    pixel noise, in [0, 255], then normalised as the model expects. Uniform noise is a poor
    test of a quantised model: its activations have ranges no real image produces.
    """
    b, c, h, w = shape
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(b, c, max(2, h // 32), max(2, w // 32), generator=g)
    fine = torch.rand(b, c, max(2, h // 8), max(2, w // 8), generator=g)
    image = 0.8 * F.interpolate(coarse, size=(h, w), mode="bicubic", align_corners=False)
    image += 0.2 * F.interpolate(fine, size=(h, w), mode="bilinear", align_corners=False)
    image += 0.02 * torch.randn(b, c, h, w, generator=g)
    pixels = (image.clamp(0, 1) * 255).round()
    mean = torch.tensor(normalisation["mean"]).view(1, 3, 1, 1)
    std = torch.tensor(normalisation["std"]).view(1, 3, 1, 1)
    return ((pixels / 255 - mean) / std).float().numpy()


def check_export(
    model: Segmenter,
    path: str | os.PathLike,
    height: int,
    width: int,
    dynamic: bool,
    tolerance: float | None = 1e-3,
    min_agreement: float | None = None,
    normalisation: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """``onnx.checker``, then ORT vs PyTorch on 3 smooth random images (another size too when
    dynamic): the max abs difference of logits and the fraction of pixels with the same argmax.

    Raises:
        ExportCheckError: the difference is above ``tolerance`` (None: not checked) or the
            agreement below ``min_agreement`` (None: not checked).
    """
    import onnx

    onnx.checker.check_model(str(path))
    p = model.patch_size
    shape = (3, 3, height + p, width + 2 * p) if dynamic else (3, 3, height, width)
    x = smooth_images(shape, normalisation or normalisation_from_config(None))
    param = next(model.parameters())
    was_training = model.training
    model.eval()
    with torch.no_grad():
        expected = model(torch.from_numpy(x).to(param.device)).float().cpu().numpy()
    model.train(was_training)
    got = OnnxSegmenter(path, providers=["CPUExecutionProvider"])(x)
    diff = float(np.abs(got - expected).max())
    agreement = float((got.argmax(1) == expected.argmax(1)).mean())
    print(
        f"onnxruntime vs PyTorch on input {list(shape)}: max abs diff of logits {diff:.3g}, "
        f"argmax agreement {100 * agreement:.2f} %"
    )
    if tolerance is not None and not diff <= tolerance:
        raise ExportCheckError(
            f"exported model {path} differs from PyTorch by {diff:.3g} (> {tolerance}) on input "
            f"{list(shape)}; export in float32 on CPU, or report the model arguments"
        )
    if min_agreement is not None and not agreement >= min_agreement:
        raise ExportCheckError(
            f"exported model {path} agrees with PyTorch on {100 * agreement:.2f} % of pixels "
            f"(< --min-agreement {100 * min_agreement:g} %); try --per-channel, --calibration "
            f"DATA or a higher precision"
        )
    return {"max_abs_diff": diff, "agreement": agreement, "check_shape": shape}


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
        prog="claravid-export",
        description="Export a claravid segmenter checkpoint to ONNX, checked with ONNX Runtime.",
        epilog="Exit status: 0 ok; 1 the export differs from PyTorch beyond --tolerance or "
        "--min-agreement (nothing written); 2 a bad argument, an unreadable checkpoint or an "
        "unusable --output.",
    )
    parser.add_argument("checkpoint_file", nargs="?", metavar="CHECKPOINT",
                        help="the same as --checkpoint")  # fmt: skip
    parser.add_argument("--checkpoint", help="checkpoint written by models.save_checkpoint")
    parser.add_argument("--output", "-o", required=True, help="output .onnx file")
    parser.add_argument("--size", type=parse_size, metavar="WxH",
                        help="input size, width x height or N for N x N, patch multiples "
                        f"(default {DEFAULT_SIZE})")  # fmt: skip
    parser.add_argument("--height", type=positive_int,
                        help="input height (older spelling; --size WxH sets both)")  # fmt: skip
    parser.add_argument("--width", type=positive_int,
                        help="input width (older spelling; --size WxH sets both)")  # fmt: skip
    parser.add_argument("--dynamic", action="store_true", help="dynamic height and width")
    parser.add_argument("--precision", choices=PRECISIONS, default="fp32",
                        help="fp32 (default), fp16 (GPUs) or int8 (CPUs)")  # fmt: skip
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
    parser.add_argument("--calibration-images", type=positive_int, default=64, metavar="N",
                        help="int8: number of calibration crops (default 64)")  # fmt: skip
    parser.add_argument("--per-channel", action="store_true",
                        help="int8: one weight scale per output channel")  # fmt: skip
    parser.add_argument(
        "--overwrite", action="store_true", help="replace an --output claravid-export did not write"
    )
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


#: ``(palette name or path) -> {"name", "names", "colors", "ignore_index"}``.
PaletteResolver = Callable[[str], dict[str, Any]]
#: ``(folder, count, (height, width), normalisation) -> batches of normalised images``.
CalibrationReader = Callable[[str, int, tuple[int, int], dict[str, Any]], Iterable[np.ndarray]]


def input_size(args: argparse.Namespace) -> tuple[int, int]:
    """``(width, height)`` from ``--size WxH``, or from the older ``--height``/``--width``
    (either one alone leaves the other at the default)."""
    if args.size is not None:
        if args.height is not None or args.width is not None:
            raise UsageError("give --size WxH or --height/--width, not both")
        return args.size
    return (args.width or DEFAULT_SIZE, args.height or DEFAULT_SIZE)


def _run(
    args: argparse.Namespace,
    resolve_palette: PaletteResolver | None = None,
    read_calibration: CalibrationReader | None = None,
) -> int:
    from claravid.models.checkpoint import model_from_checkpoint, read_checkpoint

    given = given_once(
        args.checkpoint,
        args.checkpoint_file,
        flag="--checkpoint",
        metavar="CHECKPOINT",
        what="the checkpoint",
    )
    checkpoint = Path(given)
    width, height = input_size(args)
    output = check_output_file(args.output, what="--output")
    if output.suffix.lower() != ".onnx":
        # A typo here (the checkpoint's own name, an image) would replace a file of another kind.
        raise UsageError(f"--output {output} must end in .onnx")
    # Our own earlier export may be replaced; anyone else's file only with --overwrite.
    check_output_file(output, overwrite=args.overwrite or _exported(output), what="--output")
    if args.precision != "int8" and (args.calibration is not None or args.per_channel):
        raise UsageError("--calibration and --per-channel apply to --precision int8 only")
    if args.calibration is not None and not Path(args.calibration).is_dir():
        raise UsageError(f"--calibration {args.calibration} is not a folder of images")
    if output.exists() and checkpoint.exists() and output.samefile(checkpoint):
        raise UsageError(f"--output {output} is the checkpoint itself; choose another file")
    ckpt = read_checkpoint(checkpoint)
    model = model_from_checkpoint(ckpt, checkpoint)
    patch = model.patch_size
    if width % patch or height % patch:  # said in --size terms, not as a tensor shape
        fit = [-(-v // patch) * patch for v in (width, height)]
        raise UsageError(
            f"input size {width}x{height} (WxH) is not a multiple of the model's patch size "
            f"{patch}: use --size {fit[0]}x{fit[1]}"
        )
    config = ckpt.get("config") if isinstance(ckpt.get("config"), dict) else None
    step = ckpt.get("step") if isinstance(ckpt.get("step"), int) else None
    del ckpt
    palette = None
    data = config.get("data") if config else None
    name = data.get("palette") if isinstance(data, dict) else None
    if isinstance(name, str) and resolve_palette is not None:
        palette = resolve_palette(name)
    calibration = None
    if args.calibration is not None:
        if read_calibration is None:
            raise UsageError("--calibration needs the claravid-export console script")
        normalisation = normalisation_from_config(config)
        size = (height, width)
        calibration = read_calibration(
            args.calibration, args.calibration_images, size, normalisation
        )
    try:
        result = export_onnx(
            model,
            output,
            height=height,
            width=width,
            dynamic=args.dynamic,
            check=not args.no_check,
            tolerance=args.tolerance,
            precision=args.precision,
            min_agreement=args.min_agreement,
            config=config,
            step=step,
            palette=palette,
            calibration=calibration,
            per_channel=args.per_channel,
        )
    except ExportCheckError as exc:
        print(f"claravid-export: error: {exc}; nothing was written", file=sys.stderr)
        return EXIT_FAILED
    print(f"wrote {result['path']} ({args.precision})")
    return 0


def main(
    argv: list[str] | None = None,
    *,
    resolve_palette: PaletteResolver | None = None,
    read_calibration: CalibrationReader | None = None,
) -> int:
    """``claravid-export --checkpoint CKPT --output model.onnx [--size WxH | --dynamic]``.

    Args:
        argv: The arguments (default ``sys.argv[1:]``).
        resolve_palette: Turns the checkpoint's palette name into plain data for the
            metadata (without it the file records no palette).
        read_calibration: Reads ``--calibration`` images as normalised batches.
    """

    def run(args: argparse.Namespace) -> int:
        return _run(args, resolve_palette, read_calibration)

    return run_cli("claravid-export", run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

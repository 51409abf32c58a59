"""ONNX export of a segmenter, with checks, and the ``claravid-export`` command.

We use the dynamo exporter (``torch.onnx.export(..., dynamo=True)``, the default in torch 2.9+,
through onnxscript): it handles SDPA, bicubic and symbolic H/W. The batch is always dynamic; the
example batch is 2 because a batch of 1 lets the exporter freeze that dimension.

    claravid-export runs/exp/best.pt --output model.onnx --height 630 --width 630
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shutil
import sys
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch

from claravid.cli import (
    EXIT_FAILED,
    UsageError,
    add_debug_flag,
    check_output_file,
    positive_float,
    positive_int,
    run_cli,
)
from claravid.models.onnx_runtime import META_PREFIX, OnnxSegmenter
from claravid.models.segmenter import Segmenter

# Opset 23 has a fused Attention op (SDPA maps to it; onnxruntime runs it without materialising
# the N x N score matrix in memory-bound MatMul/Softmax pairs).
OPSET = 23


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
    tolerance: float = 1e-3,
) -> dict[str, Any]:
    """Export ``model`` to ONNX, then check it with ``onnx.checker`` and ONNX Runtime.

    Args:
        model: A `Segmenter`.
        path: Output ``.onnx`` (large models also write ``<path>.data`` next to it), written
            atomically: only a complete (and, with ``check``, checked) export replaces it.
        height: Example (and, unless dynamic, the only) input height; a patch multiple.
        width: Example input width.
        dynamic: Also make H and W dynamic (multiples of the patch size).
        check: Run the checks below after export.
        tolerance: Largest allowed max-abs difference of logits between ORT and PyTorch.

    Returns:
        ``{"path", "max_abs_diff", "check_shape"}`` (diff and shape None when not checked).

    Raises:
        ValueError: the size is not a positive multiple of the patch size, or the tolerance is
            not a finite number > 0.
        ExportCheckError: ORT's logits differ from PyTorch's by more than ``tolerance`` (nothing
            is written then).
    """
    _check_settings(model, height, width, tolerance)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Written in a temp folder beside the target and moved into place once written (and checked):
    # an interrupted or failed export never leaves half a file, nor replaces a good one. The
    # folder keeps the final file name, which external weights (<name>.data) reference.
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        staged = staging / path.name
        _export(model, staged, height, width, dynamic)
        result: dict[str, Any] = {"path": path, "max_abs_diff": None, "check_shape": None}
        if check:
            try:
                result.update(check_export(model, staged, height, width, dynamic, tolerance))
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
    if (
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
    _write_metadata(path, model, None if dynamic else (height, width))


def _write_metadata(path: Path, model: Segmenter, size: tuple[int, int] | None) -> None:
    import onnx

    proto = onnx.load(str(path), load_external_data=False)
    meta = {
        "patch_size": str(model.patch_size),
        "num_classes": str(model.num_classes),
        "model_args": json.dumps(model.model_args),
    }
    if size is not None:
        meta["input_size"] = f"{size[0]}x{size[1]}"
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = META_PREFIX + key, value
    onnx.save(proto, str(path))


def check_export(
    model: Segmenter,
    path: str | os.PathLike,
    height: int,
    width: int,
    dynamic: bool,
    tolerance: float = 1e-3,
) -> dict[str, Any]:
    """``onnx.checker``, then ORT vs PyTorch on batch 3 (and another size when dynamic)."""
    import onnx

    onnx.checker.check_model(str(path))
    p = model.patch_size
    shape = (3, 3, height + p, width + 2 * p) if dynamic else (3, 3, height, width)
    param = next(model.parameters())
    x = torch.randn(*shape, generator=torch.Generator().manual_seed(0))
    was_training = model.training
    model.eval()
    with torch.no_grad():
        expected = model(x.to(param.device)).float().cpu().numpy()
    model.train(was_training)
    got = OnnxSegmenter(path, providers=["CPUExecutionProvider"])(x.numpy())
    diff = float(np.abs(got - expected).max())
    print(f"onnxruntime vs PyTorch on input {list(shape)}: max abs diff of logits {diff:.3g}")
    if not diff <= tolerance:
        raise ExportCheckError(
            f"exported model {path} differs from PyTorch by {diff:.3g} (> {tolerance}) on input "
            f"{list(shape)}; export in float32 on CPU, or report the model arguments"
        )
    return {"max_abs_diff": diff, "check_shape": shape}


def build_parser() -> argparse.ArgumentParser:
    """The ``claravid-export`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="claravid-export",
        description="Export a claravid segmenter checkpoint to ONNX, checked with ONNX Runtime.",
        epilog="Exit status: 0 ok; 1 the export differs from PyTorch beyond --tolerance (nothing "
        "written); 2 a bad argument, an unreadable checkpoint or an unusable --output.",
    )
    parser.add_argument("checkpoint", help="checkpoint written by models.save_checkpoint")
    parser.add_argument("--output", "-o", required=True, help="output .onnx file")
    parser.add_argument("--height", type=positive_int, default=630,
                        help="input height, a patch multiple (default 630)")  # fmt: skip
    parser.add_argument("--width", type=positive_int, default=630,
                        help="input width, a patch multiple (default 630)")  # fmt: skip
    parser.add_argument("--dynamic", action="store_true", help="dynamic height and width")
    parser.add_argument("--no-check", action="store_true", help="skip the ONNX Runtime check")
    parser.add_argument("--tolerance", type=positive_float, default=1e-3,
                        help="max allowed abs difference of logits (default 1e-3)")  # fmt: skip
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
    return any(p.key.startswith(META_PREFIX) for p in proto.metadata_props)


def _run(args: argparse.Namespace) -> int:
    from claravid.models.checkpoint import load_checkpoint

    output = check_output_file(args.output, what="--output")
    if output.suffix.lower() != ".onnx":
        # A typo here (the checkpoint's own name, an image) would replace a file of another kind.
        raise UsageError(f"--output {output} must end in .onnx")
    # Our own earlier export may be replaced; anyone else's file only with --overwrite.
    check_output_file(output, overwrite=args.overwrite or _exported(output), what="--output")
    checkpoint = Path(args.checkpoint)
    if output.exists() and checkpoint.exists() and output.samefile(checkpoint):
        raise UsageError(f"--output {output} is the checkpoint itself; choose another file")
    model = load_checkpoint(checkpoint)
    try:
        result = export_onnx(
            model,
            output,
            height=args.height,
            width=args.width,
            dynamic=args.dynamic,
            check=not args.no_check,
            tolerance=args.tolerance,
        )
    except ExportCheckError as exc:
        print(f"claravid-export: error: {exc}; nothing was written", file=sys.stderr)
        return EXIT_FAILED
    print(f"wrote {result['path']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``claravid-export CHECKPOINT --output model.onnx [--height --width --dynamic]``."""
    return run_cli("claravid-export", _run, build_parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())

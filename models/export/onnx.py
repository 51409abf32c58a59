"""ONNX export of a segmenter, with checks (the ``claravid-export`` command is
:mod:`claravid.eval.cli.export`).

We use the dynamo exporter (``torch.onnx.export(..., dynamo=True)``, the default in torch 2.9+,
through onnxscript): it handles SDPA, bicubic and symbolic H/W. The batch is always dynamic; the
example batch is 2 because a batch of 1 lets the exporter freeze that dimension.

    claravid-export --checkpoint runs/exp/best.pt --output model.onnx --size 630x630
    claravid-export --checkpoint runs/exp/best.pt --output model-int8.onnx --dtype int8

The file carries what it takes to run the model as evaluated (`claravid.models.export.metadata`).
The palette's colours come from the data layer, which ``models/`` never imports: the console
script (``claravid.eval.cli.export``) resolves them and passes them in :class:`Provenance`.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from claravid.models.export.graph_grid import guard_patch_grid
from claravid.models.export.metadata import (
    DTYPES,
    build_metadata,
    metadata_props,
    normalisation_from_config,
)
from claravid.models.export.runtime import OnnxSegmenter
from claravid.models.heads.specs import check_input_size
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
def _export_mode(model: Segmenter, size: tuple[int, int] | None) -> Iterator[None]:
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


@dataclass(frozen=True)
class ExportSettings:
    """How a model is exported and checked.

    Attributes:
        height: example (and, unless dynamic, the only) input height; a patch multiple.
        width: example input width.
        dynamic: also make H and W dynamic (multiples of the patch size: other sizes fail in
            ONNX Runtime itself, see `claravid.models.export.graph_grid`).
        dtype: the file's number format: ``fp32``, ``fp16`` (float16 graph, float32 input and
            output) or ``int8`` (`claravid.models.export.int8`).
        check: run ``onnx.checker`` and compare ONNX Runtime with PyTorch after export.
        tolerance: largest allowed max-abs difference of logits between ORT and PyTorch
            (default 1e-3 for fp32, 0.05 for fp16; int8 is judged by ``min_agreement``).
        min_agreement: smallest allowed fraction of pixels whose argmax equals PyTorch's
            (default 0.97 for int8, not checked otherwise).
        per_channel: int8 only: one weight scale per output channel.
    """

    height: int = DEFAULT_SIZE
    width: int = DEFAULT_SIZE
    dynamic: bool = False
    dtype: str = "fp32"
    check: bool = True
    tolerance: float | None = None
    min_agreement: float | None = None
    per_channel: bool = False


@dataclass(frozen=True)
class Provenance:
    """What the file records about where the model comes from (its metadata document).

    Attributes:
        config: the checkpoint's resolved training config (windows, normalisation, hash).
        step: the training step of the checkpoint.
        palette: ``{"name", "names", "colors", "ignore_index"}`` as plain lists.
        gsd: the checkpoint's ground sampling distance record (``{"metres_per_pixel", ...}``).
    """

    config: dict[str, Any] | None = None
    step: int | None = None
    palette: dict[str, Any] | None = None
    gsd: dict[str, Any] | None = None


def _write_graph(
    model: Segmenter, staged: Path, s: ExportSettings, calibration: Any
) -> dict[str, Any] | None:
    """The graph in ``s.dtype`` at ``staged``: exported in float32, then converted to float16
    or quantised to int8 beside it; the conversion's counts (None for float32)."""
    if s.dtype == "fp32":
        _export(model, staged, s.height, s.width, s.dynamic)
        return None
    (staged.parent / "fp32").mkdir()
    plain = staged.parent / "fp32" / staged.name
    _export(model, plain, s.height, s.width, s.dynamic)
    if s.dtype == "fp16":
        from claravid.models.export.fp16 import convert_to_fp16

        conversion = convert_to_fp16(str(plain), str(staged))
    else:
        from claravid.models.export.int8 import quantize_int8

        conversion = quantize_int8(
            plain, staged, calibration=calibration, per_channel=s.per_channel
        )
    shutil.rmtree(staged.parent / "fp32")
    return conversion


def export_onnx(
    model: Segmenter,
    path: str | os.PathLike,
    settings: ExportSettings | None = None,
    *,
    provenance: Provenance | None = None,
    calibration: Iterable[np.ndarray] | None = None,
) -> dict[str, Any]:
    """Export ``model`` to ONNX, then check it with ``onnx.checker`` and ONNX Runtime.

    The file carries the ``claravid`` metadata document (`claravid.models.export.metadata`):
    what it takes to run the model as it was evaluated.

    Args:
        model: A `Segmenter`.
        path: Output ``.onnx`` (large models also write ``<path>.data`` next to it), written
            atomically: only a complete (and, when checked, checked) export replaces it.
        settings: size, number format (dtype) and checks (default: fixed 630 x 630, fp32, checked).
        provenance: the training config, step and palette the file records.
        calibration: int8 only: batches of normalised images for static QDQ quantisation.

    Returns:
        ``{"path", "max_abs_diff", "agreement", "check_shape", "dtype", ...}`` (the
        check's entries None when not checked).

    Raises:
        ValueError: a size that is not a positive multiple of the patch size, or a tolerance,
            agreement or dtype out of range.
        ExportCheckError: ORT's logits differ from PyTorch's beyond ``tolerance`` or
            ``min_agreement`` (nothing is written then).
    """
    s = settings or ExportSettings()
    record = provenance or Provenance()
    height, width, dynamic, dtype = s.height, s.width, s.dynamic, s.dtype
    tolerance, min_agreement, per_channel = s.tolerance, s.min_agreement, s.per_channel
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    if tolerance is None:
        tolerance = DEFAULT_TOLERANCE[dtype]
    if min_agreement is None and dtype == "int8":
        min_agreement = DEFAULT_MIN_AGREEMENT
    _check_settings(model, height, width, tolerance)
    if min_agreement is not None and not (
        isinstance(min_agreement, (int, float)) and 0 <= min_agreement <= 1
    ):
        raise ValueError(f"min_agreement must be a fraction in [0, 1], got {min_agreement!r}")
    if dtype != "int8" and (calibration is not None or per_channel):
        raise ValueError("calibration and per_channel apply to int8 exports only")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Written in a temp folder beside the target and moved into place once written (and checked):
    # an interrupted or failed export never leaves half a file, nor replaces a good one. The
    # folder keeps the final file name, which external weights (<name>.data) reference.
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        staged = staging / path.name
        result: dict[str, Any] = {"path": path, "dtype": dtype}
        conversion = _write_graph(model, staged, s, calibration)
        if conversion is not None:
            result["conversion"] = conversion
        size = None if dynamic else (height, width)
        document = build_metadata(
            model.model_args,
            patch_size=model.patch_size,
            num_classes=model.num_classes,
            input_size=size,
            dtype=dtype,
            config=record.config,
            step=record.step,
            palette=record.palette,
            statistics=(model.mean, model.std),
            gsd=record.gsd,
        )
        _write_metadata(staged, document)
        result.update(max_abs_diff=None, agreement=None, check_shape=None)
        if s.check:
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
    sizes = []
    for name, value in (("height", height), ("width", width)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value <= 0:
            raise ValueError(
                f"{name} must be a positive multiple of the patch size {model.patch_size}, "
                f"got {value!r}"
            )
        sizes.append(int(value))
    model.backbone.check_input_size(*sizes)
    if "head" in model.model_args:
        height, width = sizes
        check_input_size(
            model.model_args["head"], height, width, model.patch_size, "an export size"
        )
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
    if dynamic:
        # torch.export specialises a size of 1 in the traced example: UperNet's coarsest level
        # (half the grid) would freeze at 1. Four patches a side keep every level symbolic.
        height, width = max(height, 4 * p), max(width, 4 * p)
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
    if dynamic:  # sizes off the patch grid fail in ONNX Runtime too, not only in our runner
        guard_patch_grid(path, p)


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
    dynamic): the max abs difference of logits and the fraction of pixels with the same argmax
    (returned; the command line prints them).

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

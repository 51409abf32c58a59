"""int8 quantisation of an exported float32 graph with ``onnxruntime.quantization``.

Dynamic (default): MatMul/Gemm weights stored int8, activations quantised on the fly per
batch; no data needed. The op set is restricted on purpose: with the default op set the
quantiser fuses attention into a ``com.microsoft.QAttention`` node that this ONNX Runtime
refuses to load ("Unrecognized attribute: is_causal").

Static (QDQ, with calibration images): activations' ranges are measured once on real crops
and stored as QuantizeLinear/DequantizeLinear pairs, so inference skips the per-batch range
search and Conv layers can be int8 too.

The graph is first run through ``quant_pre_process`` (shape inference and graph optimisation,
which fuses what the quantiser then sees as plain MatMuls) when that succeeds.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

#: The ops quantised dynamically (see the module docstring for why not the default set).
DYNAMIC_OPS = ["MatMul", "Gemm"]
STATIC_OPS = ["MatMul", "Gemm", "Conv"]


def _preprocess(src: Path, folder: Path) -> tuple[Path, bool]:
    """``quant_pre_process`` into ``folder``; the source itself when it cannot be applied."""
    from onnxruntime.quantization.shape_inference import quant_pre_process

    target = folder / "pre.onnx"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            quant_pre_process(str(src), str(target), skip_symbolic_shape=True)
    except Exception:  # an optimisation only: quantise the plain graph then
        return src, False
    return target, True


class _Reader:
    """``CalibrationDataReader``: one batch per call, from an iterable of float32 arrays."""

    def __init__(self, input_name: str, batches: Iterable[np.ndarray]) -> None:
        self.input_name = input_name
        self.batches: Iterator[np.ndarray] = iter(batches)

    def get_next(self) -> dict[str, np.ndarray] | None:
        batch = next(self.batches, None)
        if batch is None:
            return None
        return {self.input_name: np.ascontiguousarray(batch, dtype=np.float32)}


def quantize_int8(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    *,
    calibration: Iterable[np.ndarray] | None = None,
    per_channel: bool = False,
    preprocess: bool = True,
) -> dict[str, Any]:
    """Write the int8 version of the float32 ONNX file ``src`` to ``dst``.

    Args:
        src: The float32 export.
        dst: The int8 file to write.
        calibration: Batches of normalised images [B,3,H,W] (float32) for static QDQ
            quantisation; None for dynamic quantisation.
        per_channel: One scale per output channel of each weight (more accurate, a little
            slower to run).
        preprocess: Try ``quant_pre_process`` first.

    Returns:
        ``{"mode": "dynamic"|"static", "per_channel", "preprocessed"}``.
    """
    import onnx
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_dynamic,
        quantize_static,
    )

    with tempfile.TemporaryDirectory(prefix="claravid-quant-") as tmp:
        source, pre = _preprocess(Path(src), Path(tmp)) if preprocess else (Path(src), False)
        if calibration is None:
            quantize_dynamic(
                str(source),
                str(dst),
                op_types_to_quantize=DYNAMIC_OPS,
                per_channel=per_channel,
                weight_type=QuantType.QInt8,
            )
            mode = "dynamic"
        else:
            name = onnx.load(str(source), load_external_data=False).graph.input[0].name
            reader = type("Reader", (_Reader, CalibrationDataReader), {})(name, calibration)
            quantize_static(
                str(source),
                str(dst),
                reader,
                quant_format=QuantFormat.QDQ,
                op_types_to_quantize=STATIC_OPS,
                per_channel=per_channel,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
            )
            mode = "static"
    return {"mode": mode, "per_channel": per_channel, "preprocessed": pre}

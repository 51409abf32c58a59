"""Keeping backbone code shape-generic while it is traced or exported.

While ``torch.export`` (under the ONNX dynamo exporter) traces a model with a dynamic height and
width, those sizes are symbols. Python-side arithmetic or comparisons on them pin the exported
graph to the example's size; the helpers here keep such code inside the graph.
"""

from __future__ import annotations

from typing import Any

import torch


def is_exporting() -> bool:
    """True while tracing or exporting, when Python-side shape checks must not run.

    Not while compiling (``torch.compile``): dynamo traces the check like any Python code and
    guards on its outcome, so a compiled model refuses what the eager one refuses. Exporting
    (``torch.export``, under the ONNX exporter) must skip it: there a dynamic H and W are
    symbols the check would pin to the example's size.
    """
    return bool(
        torch.jit.is_tracing() or torch.onnx.is_in_onnx_export() or torch.compiler.is_exporting()
    )


def length_tensor(size: Any, device: torch.device | None = None) -> torch.Tensor:
    """A (possibly symbolic) size as a 0-d int64 tensor, so arithmetic on it stays in the graph.

    ``float(size)`` or ``x / size`` on a symbolic size would be evaluated once, at the example's
    value, and baked into an exported graph as a constant.
    """
    return torch.arange(size, device=device)[-1] + 1

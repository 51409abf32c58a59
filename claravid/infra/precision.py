"""The precision policy shared by training, evaluation and prediction.

``auto`` runs float32 on a CPU and autocast on CUDA (bf16 where the GPU supports it, else
fp16); ``fp32`` never autocasts; ``bf16`` and ``fp16`` autocast to that type on any device
(bf16 is fast on CPUs with AVX512-BF16 or AMX). ``train.precision``, ``WindowConfig.precision``
and the ``--precision`` flag of ``claravid-train``, ``claravid-eval`` and ``claravid-predict``
take these four names and resolve through :func:`autocast_dtype`, so a report and a training log
name the same precision the same way.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch

# torch is imported where a device or a dtype is needed, not at import: the argument check of
# every command line reads this module (`flag_precision`), and ``claravid-eval merge`` and
# ``compare`` must never pay for loading torch.

#: The precision names: ``train.precision``, ``WindowConfig.precision``, every ``--precision``
#: of a PyTorch model.
PRECISIONS = ("auto", "fp32", "bf16", "fp16")


def autocast_dtype(precision: str, device: torch.device | str) -> torch.dtype | None:
    """The autocast type a precision setting means on ``device`` (None: float32, no autocast).

    ``auto``: bf16 on a GPU that supports it, fp16 on an older GPU, float32 on a CPU.

    Raises:
        ValueError: ``precision`` is not one of `PRECISIONS`.
    """
    import torch

    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    device = torch.device(device)
    if precision == "auto":
        if device.type != "cuda":
            return None
        return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
    return {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}[precision]


def precision_name(dtype: torch.dtype | None) -> str:
    """``fp32``, ``bf16`` or ``fp16``: what `autocast_dtype` resolved to, for reports and logs."""
    import torch

    return {None: "fp32", torch.bfloat16: "bf16", torch.float16: "fp16"}[dtype]


def flag_precision(precision: str | None, *, pytorch: bool = True) -> str:
    """``--precision`` as a `WindowConfig` precision.

    Raises:
        ValueError: an unknown value, or any precision for a model that is not PyTorch (an ONNX
            file runs at the precision it was exported in, fp32, fp16 or int8: the flag would do
            nothing).
    """
    if not pytorch and precision is not None:
        raise ValueError(
            "--precision does nothing with --onnx: an ONNX file runs at the precision it was "
            "exported in (claravid-export --precision); drop it"
        )
    if precision is not None and precision not in PRECISIONS:
        raise ValueError(f"--precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return precision or "auto"


def autocast(dtype: torch.dtype | None, device: torch.device | str) -> Any:
    """An autocast context to ``dtype`` on ``device``'s type (a no-op context for None)."""
    if dtype is None:
        return contextlib.nullcontext()
    import torch

    return torch.autocast(torch.device(device).type, dtype=dtype)

"""Reading tensor files (``torch.save`` archives, safetensors) safely, with errors naming the file.

Everything is read with ``weights_only=True``: no code from the file runs. When that fails, torch's
own message advises re-running with ``weights_only=False`` ("will likely succeed"), which would
execute pickled code and would not help with a truncated or foreign file. The messages here say
what is wrong with the file instead.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path
from typing import Any

import torch


def read_tensor_file(
    path: str | os.PathLike, what: str, error: type[Exception], missing_hint: str = ""
) -> Any:
    """Load ``path`` (a safetensors file by its suffix, else ``torch.load(weights_only=True)``).

    Args:
        path: The file.
        what: How messages name it (``"checkpoint"``, ``"weights file"``).
        error: The exception class raised for an unreadable file (called with the message).
        missing_hint: Appended to the message of a missing file (what to pass instead).

    Raises:
        FileNotFoundError: the path does not exist.
        error: the path is a folder, empty, truncated, corrupt, or not a tensor file.
    """
    path = Path(path)
    if path.is_dir():
        raise error(f"{what} {path} is a folder; give the file itself{missing_hint}")
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} not found{missing_hint}")
    if path.stat().st_size == 0:
        raise error(
            f"cannot read {what} {path}: the file is empty (0 bytes); the copy or download did "
            "not finish, fetch it again"
        )
    if path.suffix == ".safetensors" or _is_safetensors(path):  # also a safetensors file renamed
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        try:
            return load_file(str(path), device="cpu")
        except SafetensorError as exc:
            raise error(
                f"cannot read {what} {path} as safetensors ({exc}): the file is truncated, "
                "corrupt or of another format"
            ) from None
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise error(f"cannot read {what} {path}: {_reason(path, exc)}") from None


def _is_safetensors(path: Path) -> bool:
    """Whether the file starts as safetensors does: an 8-byte little-endian header length, then
    the JSON header (``{``)."""
    with path.open("rb") as f:
        head = f.read(9)
    if len(head) < 9 or head[8:9] != b"{":
        return False
    return 2 <= int.from_bytes(head[:8], "little") <= path.stat().st_size - 8


def _reason(path: Path, exc: Exception) -> str:
    """Why ``torch.load`` failed, in words that do not suggest unsafe loading."""
    text = str(exc)
    if isinstance(exc, EOFError):
        return "the file ends early (truncated); copy or download it again"
    if "PytorchStreamReader" in text or isinstance(exc, zipfile.BadZipFile):
        return "the torch.save archive is truncated or corrupt; copy or download it again"
    if "Weights only load failed" in text:
        if zipfile.is_zipfile(path):
            return (
                "it holds pickled Python objects besides tensors (e.g. a whole model saved with "
                "torch.save(model)), which are not loaded because unpickling them runs code from "
                "the file; save model.state_dict() instead"
            )
        return "it is not a PyTorch tensor file (neither a torch.save archive nor a tensor pickle)"
    first = text.splitlines()[0] if text else ""
    if "weights_only" in first:
        first = ""
    return f"{type(exc).__name__}{': ' + first if first else ''}"

"""Where predictions come from: a PyTorch checkpoint or an ONNX file (or saved label maps).

A training checkpoint (``models.save_checkpoint`` with the resolved training ``config`` as an
extra entry) also says which data and palette it was trained for; :func:`checkpoint_defaults`
reads those defensively, so an older or plain model checkpoint still works when the command
line gives ``--data`` and ``--palette``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from eval.windows import Model


@dataclass
class ModelSource:
    """A loaded model and what the report says about it."""

    model: Model
    kind: str  # "checkpoint" or "onnx"
    path: str
    num_classes: int | None
    patch_size: int | None
    defaults: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> dict[str, Any]:
        """The report's ``source`` entries for the model."""
        return {"kind": self.kind, "path": self.path}


def _get(config: Any, *keys: str) -> Any:
    for key in keys:
        if not isinstance(config, Mapping) or key not in config:
            return None
        config = config[key]
    return config


def checkpoint_defaults(checkpoint: Mapping[str, Any]) -> dict[str, Any]:
    """Data root, palette, dataset kind and split a training checkpoint was made for.

    Reads ``config["data"]`` of the resolved training config (``root``, ``palette``, and when
    present ``dataset`` and ``val_split``); anything missing or of the wrong type is left out,
    so the command line's values apply.
    """
    config = checkpoint.get("config")
    out: dict[str, Any] = {}
    for name, keys in {
        "data": ("data", "root"),
        "palette": ("data", "palette"),
        "dataset": ("data", "dataset"),
        "split": ("data", "val_split"),
    }.items():
        value = _get(config, *keys)
        if isinstance(value, str | Path) and str(value):
            out[name] = str(value)
    return out


def load_source(
    checkpoint: str | Path | None = None,
    onnx: str | Path | None = None,
    *,
    device: torch.device | str = "cpu",
    threads: int | None = None,
) -> ModelSource:
    """Load exactly one of ``checkpoint`` / ``onnx``.

    Raises:
        FileNotFoundError: the file does not exist.
        models.CheckpointError: the file is not a claravid checkpoint.
    """
    if (checkpoint is None) == (onnx is None):
        raise ValueError("give exactly one of a checkpoint and an ONNX file")
    if checkpoint is not None:
        from models.checkpoint import load_checkpoint, read_checkpoint

        ckpt = read_checkpoint(checkpoint)
        defaults = checkpoint_defaults(ckpt)
        del ckpt  # load_checkpoint re-reads it; keeping both would double the memory
        model = load_checkpoint(checkpoint, map_location=device).eval()
        return ModelSource(
            model, "checkpoint", str(checkpoint), model.num_classes, model.patch_size, defaults
        )
    from models.onnx_runtime import OnnxSegmenter

    device = torch.device(device)
    providers = None if device.type == "cuda" else ["CPUExecutionProvider"]
    segmenter = OnnxSegmenter(onnx, providers=providers, threads=threads)  # type: ignore[arg-type]
    return ModelSource(
        segmenter, "onnx", str(onnx), segmenter.num_classes, segmenter.patch_size, {}
    )

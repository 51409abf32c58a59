"""Where predictions come from: a PyTorch checkpoint or an ONNX file (or saved label maps).

A training checkpoint (``claravid.models.save_checkpoint`` with the resolved training ``config``
as an extra entry) also says which data and palette it was trained for; :func:`checkpoint_defaults`
reads those defensively, so an older or plain model checkpoint still works when the command
line gives ``--data`` and ``--palette``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from claravid.eval.windows import Model


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
    """What a training checkpoint says about evaluating it: its validation data and windows.

    Reads the resolved training config (``checkpoint["config"]``): the validation dataset
    (``data.val_dataset``, ``data.val_root`` or ``data.root``, ``data.val_split``), the
    palette, the ClaraVid selection and split settings (so ``--split val`` is the very split
    training held out), and the validation windows (``val.window``, ``val.stride``,
    ``val.scale``, ``val.batch_size``). Anything missing or of the wrong type is left out, so
    the command line's values or the defaults apply.
    """
    config = checkpoint.get("config")
    out: dict[str, Any] = {}
    dataset = _get(config, "data", "val_dataset") or _get(config, "data", "dataset")
    if dataset in ("claravid", "uavid", "folder"):
        out["dataset"] = dataset
    root = _get(config, "data", "val_root") or _get(config, "data", "root")
    for name, value in {
        "data": root,
        "palette": _get(config, "data", "palette"),
        "split": _get(config, "data", "val_split"),
    }.items():
        if isinstance(value, str) and value:
            out[name] = value
    split = _get(config, "data", "split")
    if isinstance(split, Mapping):
        fields = ("block_size", "fractions", "seed", "val_missions", "test_missions")
        out["split_config"] = {k: split[k] for k in fields if k in split}
    for name in ("missions", "altitude", "direction"):
        value = _get(config, "data", name)
        if isinstance(value, list | tuple | str):
            out[name] = value
    for name in ("window", "stride", "batch_size"):
        value = _get(config, "val", name)
        if isinstance(value, int) and not isinstance(value, bool) and value > 0:
            out[name] = value
    scale = _get(config, "val", "scale")
    if isinstance(scale, int | float) and not isinstance(scale, bool) and scale > 0:
        out["scale"] = float(scale)
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
        from claravid.models.checkpoint import model_from_checkpoint, read_checkpoint

        ckpt = read_checkpoint(checkpoint)  # read once: the model and the training config
        defaults = checkpoint_defaults(ckpt)
        model = model_from_checkpoint(ckpt, checkpoint, map_location=device).eval()
        del ckpt  # the model holds its own copy of the weights now
        return ModelSource(
            model, "checkpoint", str(checkpoint), model.num_classes, model.patch_size, defaults
        )
    from claravid.models.onnx_runtime import OnnxSegmenter

    device = torch.device(device)
    providers = None if device.type == "cuda" else ["CPUExecutionProvider"]
    segmenter = OnnxSegmenter(onnx, providers=providers, threads=threads)  # type: ignore[arg-type]
    return ModelSource(
        segmenter, "onnx", str(onnx), segmenter.num_classes, segmenter.patch_size, {}
    )

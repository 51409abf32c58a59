"""Model checkpoints: a plain dict of tensors and Python values that ``weights_only`` can read.

Layout::

    {"format": "claravid-model", "version": 1,
     "model_args": {... build_model arguments ...},
     "model": state dict (without "backbone.*" when the backbone came from a weights file),
     "backbone_included": bool,
     "statistics": {"mean": [3 floats], "std": [3 floats]} (only when the model normalises
         with other statistics than its backbone's: `Segmenter.set_statistics`),
     ... whatever the caller adds (training state, the resolved training "config") ...}

A model read back normalises uint8 input as it was trained: with the file's ``statistics``,
else its training config's ``data.augment.mean/std``, else its backbone's own.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from claravid.infra.files import atomic_save
from claravid.models.export.metadata import config_get
from claravid.models.segmenter import Segmenter, build_model
from claravid.models.weights.torchfile import read_tensor_file

FORMAT = "claravid-model"
VERSION = 1
_RESERVED = {"format", "version", "model", "model_args", "backbone_included", "statistics"}


class CheckpointError(ValueError):
    """A file is not a claravid model checkpoint, or comes from a newer version."""


def save_checkpoint(
    model: Segmenter,
    path: str | os.PathLike,
    /,
    include_backbone: bool | None = None,
    **extra: Any,
) -> Path:
    """Write ``model`` atomically (temp file + rename) to ``path``.

    Args:
        model: A `Segmenter` from `build_model` (its ``model_args`` are stored).
        path: Destination file.
        include_backbone: Store the frozen backbone's weights. Default: only when they are a
            random init; weights from a file or ``"official"`` are referenced by source instead.
        **extra: Further entries (optimizer state, epoch ...); plain tensors/containers only.

    Returns:
        The path written.
    """
    if not model.model_args:
        raise ValueError("model has no model_args: build it with models.build_model")
    clash = _RESERVED & set(extra)
    if clash:
        raise ValueError(f"extra entries {sorted(clash)} are reserved names of the checkpoint")
    weights = model.model_args.get("weights")
    if include_backbone is None:
        include_backbone = weights is None
    if not include_backbone and weights is None:
        raise ValueError(
            "the backbone is a random init: it cannot be referenced by name, so it must be stored "
            "(include_backbone=True)"
        )
    state = {
        k: v.detach().cpu()
        for k, v in model.state_dict().items()
        if include_backbone or not k.startswith("backbone.")
    }
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "model_args": model.model_args,
        "model": state,
        "backbone_included": include_backbone,
        **extra,
    }
    if (model.mean, model.std) != (model.backbone.mean, model.backbone.std):
        payload["statistics"] = {"mean": list(model.mean), "std": list(model.std)}
    return atomic_save(path, lambda tmp: _torch_save(payload, tmp))


def _torch_save(payload: dict[str, Any], path: Path) -> None:
    with open(path, "wb") as f:
        torch.save(payload, f)


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read and validate a checkpoint dict (no code runs: ``weights_only=True``).

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: a folder, an empty, truncated or foreign file, a newer format version,
            or entries of the wrong type.
    """
    path = Path(path)
    ckpt = read_tensor_file(path, "checkpoint", CheckpointError)
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        keys = sorted(map(str, ckpt))[:8] if isinstance(ckpt, dict) else type(ckpt).__name__
        raise CheckpointError(
            f"{path} is not a claravid model checkpoint (found {keys}); a bare backbone weights "
            "file goes to build_model(weights=...), not load_checkpoint"
        )
    version = ckpt.get("version")
    if not isinstance(version, int) or version > VERSION:
        raise CheckpointError(
            f"{path} has checkpoint format version {version}, newer than this code's {VERSION}: "
            "upgrade claravid-toolkit to read it"
        )
    state = ckpt.get("model")
    if not isinstance(ckpt.get("model_args"), dict) or not isinstance(state, dict):
        raise CheckpointError(
            f"{path} is damaged: 'model_args' and 'model' must be dicts; save it again with "
            "models.save_checkpoint"
        )
    if not all(torch.is_tensor(v) for v in state.values()):
        raise CheckpointError(f"{path} is damaged: 'model' holds values that are not tensors")
    return ckpt


def load_checkpoint(path: str | os.PathLike, map_location: str | torch.device = "cpu") -> Segmenter:
    """Rebuild the model from the file alone (weights source included when referenced)."""
    return model_from_checkpoint(read_checkpoint(path), path, map_location)


def model_from_checkpoint(
    ckpt: dict[str, Any],
    path: str | os.PathLike = "<checkpoint>",
    map_location: str | torch.device = "cpu",
) -> Segmenter:
    """Rebuild the model from a checkpoint dict already read by `read_checkpoint`.

    For callers that also need the checkpoint's other entries (a training config), so the
    file is read once. ``path`` names the file in errors.
    """
    args = dict(ckpt["model_args"])
    included = bool(ckpt.get("backbone_included", True))
    # A stored backbone overwrites whatever init we build, so skip loading the source file.
    try:
        model = build_model(**{**args, "weights": None if included else args.get("weights")})
    except TypeError as exc:  # model_args written by hand or by another program
        raise CheckpointError(f"{path} has model_args that build_model rejects: {exc}") from None
    model.model_args = args
    state = ckpt["model"]
    own = model.state_dict()
    expected = {k for k in own if included or not k.startswith("backbone.")}
    missing, unexpected = sorted(expected - set(state)), sorted(set(state) - expected)
    if missing or unexpected:
        raise CheckpointError(
            f"{path} does not match its model_args: missing {missing[:10]}, "
            f"unexpected {unexpected[:10]}"
        )
    shapes = [
        f"{k}: file {tuple(state[k].shape)} vs model {tuple(own[k].shape)}"
        for k in sorted(set(state) & set(own))
        if state[k].shape != own[k].shape
    ]
    if shapes:
        raise CheckpointError(f"{path} does not match its model_args: {'; '.join(shapes[:5])}")
    model.load_state_dict(state, strict=included)
    mean, std = recorded_statistics(ckpt)
    if mean is not None:
        try:
            model.set_statistics(mean, std)
        except ValueError as exc:
            raise CheckpointError(f"{path} records unusable input statistics: {exc}") from None
    return model.to(map_location)


def recorded_statistics(ckpt: dict[str, Any]) -> tuple[Any, Any]:
    """``(mean, std)`` a checkpoint says its model was trained with: its ``statistics`` entry,
    else its training config's ``data.augment.mean/std``; ``(None, None)`` when it says none."""
    for keys in (("statistics",), ("config", "data", "augment")):
        mean, std = config_get(ckpt, *keys, "mean"), config_get(ckpt, *keys, "std")
        if mean is not None and std is not None:
            return mean, std
    return None, None

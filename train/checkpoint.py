"""Training checkpoints: ``claravid.models.save_checkpoint``'s model file plus what resume needs.

``last.pt`` and ``best.pt`` are both complete model files (``claravid-eval`` and
``claravid-export`` read them) holding also::

    "step", "config" (the resolved config), "optimizer", "scheduler", "scaler",
    "rng" (torch, cuda, numpy, python), "sampler" ({"step", "frames_seen"}),
    "best_miou", "best_step", "metrics" (the last validation row),
    "classes" (the class names, in train-id order), "budget" (the label budget drawn:
    `claravid.train.budget.Budget.record`), "init" (the checkpoint ``model.init`` started
    from, or None)

Everything is a tensor or a plain container, so ``torch.load(weights_only=True)`` reads it,
and the file is written to a temp file and renamed: a kill at any moment leaves the previous
file or the new one.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from claravid import models
from claravid.models.checkpoint import read_checkpoint


def rng_state() -> dict[str, Any]:
    """torch, CUDA, numpy and python RNG states as tensors and plain lists."""
    # The legacy global numpy RNG: we draw from our own generators, but libraries may not.
    state = np.random.get_state(legacy=True)  # noqa: NPY002
    assert isinstance(state, tuple)  # the global generator is MT19937: the legacy tuple
    kind, keys, pos, has_gauss, cached = state
    version, internal, gauss = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": {
            "kind": kind,
            "keys": torch.from_numpy(keys.astype(np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached),
        },
        "python": {"version": version, "state": list(internal), "gauss": gauss},
    }


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what `rng_state` saved (CUDA states only when as many devices are present)."""
    torch.set_rng_state(state["torch"])
    cuda = state.get("cuda") or []
    if cuda and torch.cuda.is_available() and len(cuda) == torch.cuda.device_count():
        torch.cuda.set_rng_state_all(cuda)
    n = state["numpy"]
    np.random.set_state(  # noqa: NPY002
        (
            n["kind"],
            n["keys"].numpy().astype(np.uint32),
            n["pos"],
            n["has_gauss"],
            n["cached_gaussian"],
        )
    )
    p = state["python"]
    random.setstate((p["version"], tuple(p["state"]), p["gauss"]))


def save_training_checkpoint(
    path: Path,
    model: models.Segmenter,
    *,
    step: int,
    config: dict[str, Any],
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    scaler: torch.amp.GradScaler,
    frames_per_step: int,
    best_miou: float | None,
    best_step: int | None,
    metrics: dict[str, Any] | None,
    backbone_trained: bool,
    gsd: dict[str, Any] | None = None,
    **records: Any,
) -> Path:
    """Write a complete, resumable checkpoint atomically (see the module docstring).

    ``records``: further plain entries (``classes``, ``budget``, ``init``).
    """
    return models.save_checkpoint(
        model,
        path,
        # A trained (or loaded) backbone is no longer the weights file it came from: store it.
        include_backbone=True if backbone_trained else None,
        step=int(step),
        config=config,
        optimizer=optimizer.state_dict(),
        scheduler=scheduler.state_dict(),
        scaler=scaler.state_dict(),
        rng=rng_state(),
        sampler={"step": int(step), "frames_seen": int(step) * int(frames_per_step)},
        best_miou=best_miou,
        best_step=best_step,
        metrics=metrics or {},
        gsd=gsd,  # the training images' metres per pixel (claravid.data.gsd), or None
        **records,
    )


def load_training_checkpoint(path: Path) -> dict[str, Any]:
    """Read a training checkpoint (``weights_only``) and check it carries the training state."""
    ckpt = read_checkpoint(path)
    missing = [k for k in ("step", "config", "optimizer", "scheduler", "rng") if k not in ckpt]
    if missing:
        raise ValueError(
            f"{path} is a model file without training state (no {', '.join(missing)}); "
            "it cannot be resumed: start a new out_dir"
        )
    return ckpt


def restore_model(model: models.Segmenter, ckpt: dict[str, Any]) -> None:
    """Load a checkpoint's weights into the freshly built model (backbone when stored)."""
    strict = bool(ckpt.get("backbone_included", True))
    model.load_state_dict(ckpt["model"], strict=strict)

"""The optimiser and its schedule: AdamW on the trained parameters, linear warmup, then poly or
cosine decay (the DINOv2 / Depth-Anything DPT recipe; the paper publishes none).
"""

from __future__ import annotations

import math

import torch
from omegaconf import DictConfig
from torch import nn


def lr_factor(
    step: int, total: int, warmup: int, schedule: str, power: float, floor: float
) -> float:
    """Multiplier of the base learning rate at ``step`` (0-based; the step about to be taken).

    Linear warmup over ``warmup`` steps (from 1/warmup, never 0: step 0 learns), then from 1 to
    ``floor`` over the remaining steps, polynomially (``power``) or along a half cosine.
    """
    if warmup > 0 and step < warmup:
        return (step + 1) / warmup
    span = max(1, total - warmup)
    progress = min(1.0, (step - warmup) / span)
    if schedule == "poly":
        decay = (1.0 - progress) ** power
    elif schedule == "cosine":
        decay = 0.5 * (1.0 + math.cos(math.pi * progress))
    else:
        raise ValueError(f"unknown schedule {schedule!r}: poly or cosine")
    return floor + (1.0 - floor) * decay


def build_optimizer(model: nn.Module, cfg: DictConfig) -> torch.optim.AdamW:
    """AdamW over the head (and the backbone when it is trained), no decay on biases and norms.

    ``model`` is the `Segmenter`; a frozen backbone has ``requires_grad=False`` and is left out.
    """
    t = cfg.train
    groups: dict[tuple[str, bool], list[nn.Parameter]] = {}
    for name, p in model.named_parameters():
        if not p.requires_grad:
            continue
        part = "backbone" if name.startswith("backbone.") else "head"
        decay = p.ndim > 1 and "pos_embed" not in name and "token" not in name
        groups.setdefault((part, decay), []).append(p)
    if not groups:
        raise ValueError("the model has no trainable parameter")
    param_groups = [
        {
            "params": params,
            "lr": t.backbone_lr if part == "backbone" else t.lr,
            "weight_decay": t.weight_decay if decay else 0.0,
            "name": f"{part}{'' if decay else '_no_decay'}",
        }
        for (part, decay), params in sorted(groups.items())
    ]
    return torch.optim.AdamW(param_groups, betas=tuple(t.betas))


def build_scheduler(
    optimizer: torch.optim.Optimizer, cfg: DictConfig, total_steps: int
) -> torch.optim.lr_scheduler.LambdaLR:
    """`lr_factor` as a LambdaLR (its state, the step count, goes into checkpoints)."""
    t = cfg.train
    warmup = min(t.warmup_steps, max(0, total_steps - 1))

    def factor(step: int) -> float:
        return lr_factor(step, total_steps, warmup, t.schedule, t.poly_power, t.min_lr_ratio)

    return torch.optim.lr_scheduler.LambdaLR(optimizer, factor)


def clip_gradients(model: nn.Module, max_norm: float) -> float:
    """Clip the global gradient norm (0: off); returns the norm before clipping."""
    params = [p for p in model.parameters() if p.grad is not None]
    if max_norm <= 0:
        norms = [grad.detach().norm() for p in params if (grad := p.grad) is not None]
        return float(torch.stack(norms).norm()) if norms else 0.0
    return float(torch.nn.utils.clip_grad_norm_(params, max_norm))

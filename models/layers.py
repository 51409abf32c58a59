"""Building blocks shared by the DINOv2 and DINOv3 vision transformers.

Parameter names are the official ones of both ``facebookresearch/dinov2`` and
``facebookresearch/dinov3`` (``patch_embed.proj``, ``mlp.fc1``/``fc2``, ``ls1.gamma``), so the
official checkpoints load without renaming.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn


class PatchEmbed(nn.Module):
    """Non-overlapping patches -> tokens: one strided convolution, flattened to [B, N, D]."""

    def __init__(self, patch_size: int, in_chans: int, embed_dim: int) -> None:
        super().__init__()
        self.proj = nn.Conv2d(in_chans, embed_dim, kernel_size=patch_size, stride=patch_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)


class Mlp(nn.Module):
    """fc1 -> exact GELU -> fc2."""

    def __init__(self, dim: int, hidden: int, bias: bool = True) -> None:
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden, bias=bias)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim, bias=bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


def swiglu_hidden(dim: int, mlp_ratio: float = 4.0, align: int = 8) -> int:
    """Hidden width of the official SwiGLU feed-forwards.

    2/3 of the MLP width ``int(dim * mlp_ratio)`` (so the three SwiGLU matrices cost what the two
    MLP matrices would), rounded up to a multiple of ``align``: 8 in DINOv2's giant model and
    DINOv3's S+/H+, 64 in DINOv3's 7B model.
    """
    width = int(int(dim * mlp_ratio) * 2 / 3)
    return -(-width // align) * align


class LayerScale(nn.Module):
    """Per-channel learned scale of a residual branch."""

    def __init__(self, dim: int, init_value: float = 1.0) -> None:
        super().__init__()
        self.gamma = nn.Parameter(torch.full((dim,), init_value))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.gamma


def block_indices(n: int | Sequence[int], depth: int) -> list[int]:
    """``get_intermediate_layers``' ``n``: the last ``n`` blocks if an int, else the indices."""
    take = list(range(depth - n, depth)) if isinstance(n, int) else [int(i) for i in n]
    bad = [i for i in take if not 0 <= i < depth]
    if bad or not take:
        raise ValueError(f"block indices {take} must be in [0, {depth - 1}] and non-empty")
    return take


def layer_outputs(
    outputs: list[torch.Tensor],
    norm: nn.Module | None,
    num_prefix_tokens: int,
    grid: tuple[int, int],
    reshape: bool,
    return_class_token: bool,
) -> tuple[Any, ...]:
    """Block outputs [B, T, D] as ``get_intermediate_layers`` returns them (both ViT families):
    through ``norm`` when given, prefix tokens (CLS, registers) dropped from the patch tokens,
    [B, D, h, w] when ``reshape``, (patches, CLS) pairs when ``return_class_token``."""
    if norm is not None:
        outputs = [norm(o) for o in outputs]
    cls = [o[:, 0] for o in outputs]
    patches = [o[:, num_prefix_tokens:] for o in outputs]
    if reshape:
        gh, gw = grid
        patches = [
            p.reshape(p.shape[0], gh, gw, -1).permute(0, 3, 1, 2).contiguous() for p in patches
        ]
    if return_class_token:
        return tuple(zip(patches, cls, strict=True))
    return tuple(patches)

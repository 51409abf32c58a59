"""Building blocks shared by the DINOv2 and DINOv3 vision transformers (attention is
`claravid.models.layers.attention`).

Parameter names are the official ones of both ``facebookresearch/dinov2`` and
``facebookresearch/dinov3`` (``patch_embed.proj``, ``mlp.fc1``/``fc2``, ``mlp.w12``,
``mlp.w1``/``w2``/``w3``, ``ls1.gamma``), so the official checkpoints load without renaming.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from claravid.models.layers.attention import Attention


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


class SwiGLUFused(nn.Module):
    """w12 -> (silu(x1) * x2) -> w3: DINOv2 giant's feed-forward (one fused input matrix)."""

    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.w12 = nn.Linear(dim, 2 * hidden)
        self.w3 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x1, x2 = self.w12(x).chunk(2, dim=-1)
        return self.w3(F.silu(x1) * x2)


class SwiGLU(nn.Module):
    """w3(silu(w1 x) * w2 x): DINOv3's gated feed-forward (three separate matrices)."""

    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.w1 = nn.Linear(dim, hidden)
        self.w2 = nn.Linear(dim, hidden)
        self.w3 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.w3(F.silu(self.w1(x)) * self.w2(x))


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


class Block(nn.Module):
    """Pre-norm transformer block: x += ls1(attn(norm1 x, rope)); x += ls2(mlp(norm2 x)).

    Args:
        dim: Token width.
        attn: The attention module.
        mlp: The feed-forward module.
        eps: LayerNorm epsilon (1e-6 in DINOv2, 1e-5 in DINOv3).
    """

    def __init__(self, dim: int, attn: Attention, mlp: nn.Module, eps: float) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = attn
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = mlp
        self.ls2 = LayerScale(dim)

    def forward(
        self, x: torch.Tensor, rope: tuple[torch.Tensor, torch.Tensor] | None = None
    ) -> torch.Tensor:
        x = x + self.ls1(self.attn(self.norm1(x), rope))
        return x + self.ls2(self.mlp(self.norm2(x)))

"""Axial rotary position embedding (RoPE) of the DINOv3 patch tokens, without learned weights.

For a patch grid of ``h`` rows and ``w`` columns and a head width ``d`` (a multiple of 4):

- each patch centre gets coordinates ``c_y = (i + 0.5) / h`` and ``c_x = (j + 0.5) / w``, mapped
  to ``2c - 1`` in (-1, 1) (rows and columns normalised separately, the official
  ``normalize_coords="separate"``);
- ``periods[k] = base ** (2k / (d/2))`` for ``k < d/4`` (base 100 in every official model);
- the angles ``2 pi c / periods`` of y, then of x, give ``d/2`` values, tiled twice to ``d``;
- queries and keys of the patch tokens (never CLS or storage tokens) become
  ``x * cos + rotate_half(x) * sin`` with ``rotate_half([a, b]) = [-b, a]``.

Everything is computed in float32, also under autocast and in a model cast to bfloat16: the
angles reach hundreds of radians at the finest period, where bfloat16 would keep no digits of
the phase. The official training-only coordinate augmentations (shift, jitter, rescale) are never
applied: the backbones here are frozen and run in eval mode.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from claravid.models.tracing import length_tensor


def rope_periods(head_dim: int, base: float = 100.0) -> torch.Tensor:
    """The ``head_dim // 4`` float32 periods ``base ** (2k / (head_dim / 2))``.

    The official checkpoints store them as the buffer ``rope_embed.periods``.
    """
    if head_dim % 4:
        raise ValueError(f"RoPE needs a head width divisible by 4, got {head_dim}")
    exponents = 2 * torch.arange(head_dim // 4, dtype=torch.float32) / (head_dim // 2)
    return base**exponents


def patch_coordinates(grid_h: Any, grid_w: Any, device: torch.device | None = None) -> torch.Tensor:
    """[grid_h * grid_w, 2] float32 (y, x) patch centres in (-1, 1), rows first (row-major).

    The sizes may be symbolic while exporting: they enter as tensors (`length_tensor`), not as
    Python numbers that the exporter would freeze.
    """
    ys = (torch.arange(grid_h, dtype=torch.float32, device=device) + 0.5) / length_tensor(
        grid_h, device
    )
    xs = (torch.arange(grid_w, dtype=torch.float32, device=device) + 0.5) / length_tensor(
        grid_w, device
    )
    coords = torch.stack(torch.meshgrid(ys, xs, indexing="ij"), dim=-1).reshape(-1, 2)
    return 2.0 * coords - 1.0


def rope_angles(coords: torch.Tensor, periods: torch.Tensor) -> torch.Tensor:
    """[N, d] angles: ``2 pi c / periods`` of y, then of x (d/2 values), tiled twice."""
    angles = 2 * math.pi * coords[:, :, None] / periods[None, None, :]  # [N, 2, d/4]
    return angles.flatten(1, 2).tile(2)


def rotate_half(x: torch.Tensor) -> torch.Tensor:
    """``[a, b] -> [-b, a]`` over the two halves of the last dimension."""
    a, b = x.chunk(2, dim=-1)
    return torch.cat((-b, a), dim=-1)


def rope_apply(x: torch.Tensor, sin: torch.Tensor, cos: torch.Tensor) -> torch.Tensor:
    """Rotate ``x`` [..., N, d] by the angles whose sin and cos are given ([N, d]), in float32.

    The result has ``x``'s dtype.
    """
    x32 = x.float()
    return (x32 * cos + rotate_half(x32) * sin).to(x.dtype)


class RopePositionEmbedding(nn.Module):
    """sin and cos [h*w, head_dim] of a patch grid (float32, no learned weights).

    Args:
        head_dim: Attention head width (embed_dim / num_heads), a multiple of 4.
        base: Period base (100 in the official models).

    The buffer ``periods`` exists so that official checkpoints load strictly (their loader checks
    it against `rope_periods`); the angles are computed from periods recomputed in float32 each
    call, so a model cast to bfloat16 does not round them.
    """

    def __init__(self, head_dim: int, base: float = 100.0) -> None:
        super().__init__()
        self.head_dim = head_dim
        self.base = float(base)
        self.register_buffer("periods", rope_periods(head_dim, base), persistent=True)
        # sin/cos precomputed for one grid (see `freeze`), or None.
        self._frozen: tuple[tuple[int, int], torch.Tensor, torch.Tensor] | None = None

    def forward(self, grid_h: Any, grid_w: Any) -> tuple[torch.Tensor, torch.Tensor]:
        """(sin, cos), each [grid_h * grid_w, head_dim] float32."""
        frozen = self._frozen
        if frozen is not None and frozen[0] == (grid_h, grid_w):
            return frozen[1], frozen[2]
        device = self.periods.device
        # Float32 inputs keep every op here float32: autocast only lowers matrix products and
        # convolutions, none of which occur.
        periods = rope_periods(self.head_dim, self.base).to(device)
        angles = rope_angles(patch_coordinates(grid_h, grid_w, device), periods)
        return torch.sin(angles), torch.cos(angles)

    def freeze(self, grid_h: int | None, grid_w: int | None = None) -> None:
        """Store sin/cos for one grid (a fixed-size export then holds them as constants).

        ``None`` clears them; other grids are computed as usual either way.
        """
        self._frozen = None
        if grid_h is None:
            return
        grid_w = grid_h if grid_w is None else grid_w
        with torch.no_grad():
            sin, cos = self(grid_h, grid_w)
        self._frozen = ((grid_h, grid_w), sin.detach().clone(), cos.detach().clone())

    def extra_repr(self) -> str:
        return f"head_dim={self.head_dim}, base={self.base:g}"

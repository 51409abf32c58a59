"""Axial rotary position embedding (RoPE) of the DINOv3 patch tokens, without learned weights.

For a patch grid of ``h`` rows and ``w`` columns and a head width ``d`` (a multiple of 4):

- each patch centre gets coordinates ``c_y = (i + 0.5) / h`` and ``c_x = (j + 0.5) / w``, mapped
  to ``2c - 1`` in (-1, 1) (rows and columns normalised separately, the official
  ``normalize_coords="separate"``);
- ``periods[k] = base ** (2k / (d/2))`` for ``k < d/4`` (base 100 in every official model),
  rounded through the dtype the model was trained with: the released distilled models (ViT-S,
  S+, B, L, H+, SAT ViT-L) were trained with bfloat16 RoPE and their files hold bfloat16 periods
  (1.0, 1.3359375, 1.78125, ... for d = 64, not 1.0, 1.33352, 1.77828, ...); the 7B models used
  float32;
- the angles ``2 pi c / periods`` of y, then of x, give ``d/2`` values, tiled twice to ``d``;
- queries and keys of the patch tokens (never CLS or storage tokens) become
  ``x * cos + rotate_half(x) * sin`` with ``rotate_half([a, b]) = [-b, a]``.

The angles are computed from the ``periods`` buffer, as the official code does: a loaded file's
periods are the ones used. Everything is computed in float32, also under autocast and in a
model cast to bfloat16 (the buffer stays float32): the angles reach hundreds of radians at the
finest period, where bfloat16 would keep no digits of the phase. The official training-only
coordinate augmentations (shift, jitter, rescale) are never applied: the backbones here are
frozen and run in eval mode.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from claravid.models.layers.tracing import length_tensor

#: The dtypes RoPE was trained in, by the name the official configs give them.
ROPE_DTYPES = {"fp32": torch.float32, "bf16": torch.bfloat16}


def rope_periods(head_dim: int, base: float = 100.0, dtype: str = "fp32") -> torch.Tensor:
    """The ``head_dim // 4`` periods ``base ** (2k / (head_dim / 2))``, as a float32 tensor.

    Args:
        head_dim: Attention head width, a multiple of 4.
        base: Period base (100 in the official models).
        dtype: ``"fp32"``, or ``"bf16"`` for the values rounded to bfloat16, as the files of the
            models trained with bfloat16 RoPE hold them (the buffer ``rope_embed.periods``).
    """
    if head_dim % 4:
        raise ValueError(f"RoPE needs a head width divisible by 4, got {head_dim}")
    if dtype not in ROPE_DTYPES:
        raise ValueError(f"unknown RoPE dtype {dtype!r}: use one of {', '.join(ROPE_DTYPES)}")
    exponents = 2 * torch.arange(head_dim // 4, dtype=torch.float32) / (head_dim // 2)
    return (base**exponents).to(ROPE_DTYPES[dtype]).float()


#: How far stored periods may lie from the formula: one bfloat16 step (8 significant bits), so
#: the released files (periods rounded to bfloat16) and state dicts saved in float16 or bfloat16
#: pass, while periods of another base (or of minimum/maximum periods) do not.
PERIODS_RTOL = 2.0**-7


def check_periods(periods: torch.Tensor, head_dim: int, base: float) -> None:
    """Refuse stored periods (``rope_embed.periods`` of a file) of another base than ``base``.

    Values within a bfloat16 rounding (`PERIODS_RTOL`) of ``base ** (2k / (d/2))`` pass: the
    loaded values are then the ones the model uses, as in the official code. Periods of another
    shape pass too (a strict load reports the shape).

    Raises:
        ValueError: the periods differ; the message gives the first ones, the expected ones and
            the base they fit.
    """
    expected = rope_periods(head_dim, base)
    if periods.shape != expected.shape:
        return
    got = periods.float()
    if bool(((got - expected).abs() <= PERIODS_RTOL * expected).all()):
        return
    fit = ""
    if len(got) > 1 and bool(got[-1] > 0):
        # periods[k] = base ** (4k / d): the last one tells the base.
        fit = f" (they fit base {float(got[-1]) ** (head_dim / (4 * (len(got) - 1))):.4g})"
    raise ValueError(
        f"rope_embed.periods {got[:4].tolist()}... differ from base {base:g} "
        f"** (2k / {head_dim // 2}) = {expected[:4].tolist()}... by more than bfloat16 "
        f"rounding{fit}"
    )


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
        dtype: The dtype the periods were trained in (`rope_periods`): the initial ``periods``
            are rounded through it. A loaded state dict replaces them.

    The angles are computed from the buffer ``periods`` (float32), which official files hold
    and which loads with them. Casting the module (``.to(torch.bfloat16)``, ``.half()``) moves
    the buffer but keeps it float32, so the periods are never rounded again.
    """

    periods: torch.Tensor  # a buffer

    def __init__(self, head_dim: int, base: float = 100.0, dtype: str = "fp32") -> None:
        super().__init__()
        self.head_dim = head_dim
        self.base = float(base)
        self.dtype = dtype
        self.register_buffer("periods", rope_periods(head_dim, base, dtype), persistent=True)
        # sin/cos precomputed for one grid (see `freeze`), or None.
        self._frozen: tuple[tuple[int, int], torch.Tensor, torch.Tensor] | None = None

    def forward(self, grid_h: Any, grid_w: Any) -> tuple[torch.Tensor, torch.Tensor]:
        """(sin, cos), each [grid_h * grid_w, head_dim] float32."""
        frozen = self._frozen
        if frozen is not None and frozen[0] == (grid_h, grid_w):
            return frozen[1], frozen[2]
        periods = self.periods.float()
        # Float32 inputs keep every op here float32: autocast only lowers matrix products and
        # convolutions, none of which occur.
        angles = rope_angles(patch_coordinates(grid_h, grid_w, periods.device), periods)
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

    def _apply(self, fn: Any, recurse: bool = True) -> RopePositionEmbedding:
        # A cast of the whole model would round the periods (7B's float32 ones to bfloat16):
        # keep them float32, on the device the cast moved them to.
        periods = self.periods
        super()._apply(fn, recurse)
        if self.periods.dtype != periods.dtype:
            self.periods = periods.to(self.periods.device)
        return self

    def extra_repr(self) -> str:
        return f"head_dim={self.head_dim}, base={self.base:g}, dtype={self.dtype}"

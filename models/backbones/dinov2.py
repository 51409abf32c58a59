"""DINOv2 vision transformer in plain PyTorch, key-compatible with the official checkpoints.

The trunk (blocks, checks, ``get_intermediate_layers``) is `claravid.models.backbones.trunk`'s;
DINOv2
brings its tokens and positions: a learned positional table added to [CLS, patches], then the
registers, giving [CLS, registers, patches]. The table is resized as the official code does:
bicubic in float32 with the ``+0.1`` offset (no registers) or to the exact size with antialias
(registers). Parameter names follow ``facebookresearch/dinov2`` (``blocks.N.attn.qkv``,
``ls1.gamma``, ``mlp.w12`` ...) so an official ``.pth`` loads unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from claravid.models.backbones.trunk import VisionTransformer
from claravid.models.layers.attention import Attention
from claravid.models.layers.blocks import Mlp, SwiGLUFused, swiglu_hidden
from claravid.models.layers.tracing import is_exporting, length_tensor


def bicubic_matrix(out_size: Any, in_size: int, offset: float) -> torch.Tensor:
    """[out_size, in_size] matrix of PyTorch's bicubic resize along one axis.

    Same rule as ``F.interpolate(mode="bicubic", scale_factor=(out_size + offset) / in_size)``:
    source position (i + 0.5) / scale - 0.5, Keys cubic with a = -0.75, borders clamped. Built
    from tensor ops so that ``out_size`` may be symbolic while exporting (no float() on it,
    which would specialise the exported graph to the example size).
    """
    a = -0.75
    index = torch.arange(out_size, dtype=torch.float64)
    # out_size as a tensor (index[-1] + 1): Python arithmetic on it would be specialised.
    inv_scale = in_size / (index[-1] + 1 + offset)
    src = (index + 0.5) * inv_scale - 0.5
    left = torch.floor(src)
    t = src - left
    # Weights of the 4 taps at left-1, left, left+1, left+2.
    weights = torch.stack(
        [
            ((a * (t + 1) - 5 * a) * (t + 1) + 8 * a) * (t + 1) - 4 * a,
            ((a + 2) * t - (a + 3)) * t * t + 1,
            ((a + 2) * (1 - t) - (a + 3)) * (1 - t) * (1 - t) + 1,
            ((a * (2 - t) - 5 * a) * (2 - t) + 8 * a) * (2 - t) - 4 * a,
        ],
        dim=1,
    )
    taps = left.long().unsqueeze(1) + torch.arange(-1, 3).unsqueeze(0)
    onehot = F.one_hot(taps.clamp(0, in_size - 1), in_size).to(weights.dtype)
    return (onehot * weights.unsqueeze(-1)).sum(dim=1).float()


def _identity(size: Any, in_size: int) -> torch.Tensor:
    """[size, in_size] rows of the identity (only used where size == in_size)."""
    rows = torch.arange(size).clamp(max=in_size - 1)
    return F.one_hot(rows, in_size).to(torch.float32)


class DinoVisionTransformer(VisionTransformer):
    """DINOv2 ViT backbone.

    The official sizes' arguments are in `claravid.models.backbones.specs` (``build_backbone``).

    Args:
        embed_dim: Token width D.
        depth: Number of blocks.
        num_heads: Attention heads.
        patch_size: Patch side in pixels.
        img_size: Training resolution; the stored positional grid is img_size // patch_size.
        mean: Per-channel input mean (RGB, pixels in [0, 1]) of the weights' training data.
        std: Per-channel input std.
        num_register_tokens: Extra learned tokens without positional embedding (0 or 4).
        ffn: ``"mlp"`` (GELU MLP) or ``"swiglu"`` (giant).
        mlp_ratio: Feed-forward expansion.
        interpolate_offset: Added to the target grid before computing the bicubic scale factor
            (0.1 in the official models without registers); 0 means resize to the exact size.
        interpolate_antialias: Antialiased bicubic (the official register models).
    """

    def __init__(
        self,
        *,
        embed_dim: int,
        depth: int,
        num_heads: int,
        patch_size: int,
        img_size: int,
        mean: Sequence[float],
        std: Sequence[float],
        num_register_tokens: int = 0,
        ffn: str = "mlp",
        mlp_ratio: float = 4.0,
        interpolate_offset: float = 0.1,
        interpolate_antialias: bool = False,
    ) -> None:
        if img_size % patch_size:
            raise ValueError(f"img_size {img_size} is not a multiple of patch_size {patch_size}")
        super().__init__(
            embed_dim=embed_dim,
            depth=depth,
            num_heads=num_heads,
            patch_size=patch_size,
            mean=mean,
            std=std,
        )
        self.num_register_tokens = num_register_tokens
        self.interpolate_offset = interpolate_offset
        self.interpolate_antialias = interpolate_antialias
        grid = img_size // patch_size
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + grid * grid, embed_dim))
        if num_register_tokens:
            self.register_tokens: nn.Parameter | None = nn.Parameter(
                torch.zeros(1, num_register_tokens, embed_dim)
            )
        else:
            self.register_tokens = None
        if ffn == "mlp":
            hidden = int(embed_dim * mlp_ratio)
        elif ffn == "swiglu":
            hidden = swiglu_hidden(embed_dim, mlp_ratio)
        else:
            raise ValueError(f"unknown ffn {ffn!r}: use 'mlp' or 'swiglu'")
        feed_forward = Mlp if ffn == "mlp" else SwiGLUFused
        self._add_blocks(
            lambda: Attention(embed_dim, num_heads),
            lambda: feed_forward(embed_dim, hidden),
            norm_eps=1e-6,
        )
        # Positional embedding precomputed for one grid (see `freeze_pos_embed`), or None.
        self._frozen_pos: tuple[tuple[int, int], torch.Tensor] | None = None
        self._init_weights()

    def _init_weights(self) -> None:
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        nn.init.normal_(self.cls_token, std=1e-6)
        if self.register_tokens is not None:
            nn.init.normal_(self.register_tokens, std=1e-6)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                nn.init.zeros_(m.bias)

    @property
    def num_prefix_tokens(self) -> int:
        """CLS plus registers, ahead of the patch tokens."""
        return 1 + self.num_register_tokens

    def interpolate_pos_encoding(self, grid_h: int, grid_w: int) -> torch.Tensor:
        """Positional embedding [1, 1 + grid_h*grid_w, D] for a patch grid, official semantics."""
        if self._frozen_pos is not None and self._frozen_pos[0] == (grid_h, grid_w):
            return self._frozen_pos[1]
        n = self.pos_embed.shape[1] - 1
        m = int(math.sqrt(n))
        exporting = is_exporting()
        # A Python test on symbolic sizes would specialise an export to one side of it.
        if not exporting and (grid_h, grid_w) == (m, m):
            return self.pos_embed
        pos = self.pos_embed.float()
        patch_pos = pos[:, 1:].reshape(1, m, m, -1).permute(0, 3, 1, 2)
        if self.interpolate_offset and exporting and not self.interpolate_antialias:
            # Exporters bake a float scale_factor into a constant; the same resize as a product
            # with interpolation matrices stays shape-generic. At the native grid the official
            # code uses the table as is, which identity matrices reproduce.
            native = (length_tensor(grid_h) == m) & (length_tensor(grid_w) == m)
            rows = torch.where(
                native, _identity(grid_h, m), bicubic_matrix(grid_h, m, self.interpolate_offset)
            )
            cols = torch.where(
                native, _identity(grid_w, m), bicubic_matrix(grid_w, m, self.interpolate_offset)
            )
            patch_pos = rows.to(patch_pos) @ patch_pos @ cols.to(patch_pos).T
        elif self.interpolate_offset:
            # The official models scale by (grid + 0.1) / M so that floor() lands on the grid;
            # the scale itself (not the size) sets the sampling positions, so keep it.
            scale = (
                float(grid_h + self.interpolate_offset) / m,
                float(grid_w + self.interpolate_offset) / m,
            )
            patch_pos = F.interpolate(
                patch_pos, scale_factor=scale, mode="bicubic", antialias=self.interpolate_antialias
            )
        else:
            patch_pos = F.interpolate(
                patch_pos,
                size=(grid_h, grid_w),
                mode="bicubic",
                antialias=self.interpolate_antialias,
            )
        patch_pos = patch_pos.permute(0, 2, 3, 1).reshape(1, grid_h * grid_w, -1)
        return torch.cat((pos[:, :1], patch_pos), dim=1).to(self.pos_embed.dtype)

    def freeze_pos_embed(self, height: int | None, width: int | None = None) -> None:
        """Precompute the positional embedding for one input size (``None`` clears it).

        Used for fixed-size ONNX export: antialiased bicubic resize does not export cleanly, and
        a stored table is also faster.
        """
        if height is None:
            self._frozen_pos = None
            return
        width = height if width is None else width
        self.check_input_size(height, width)
        grid = (height // self.patch_size, width // self.patch_size)
        self._frozen_pos = None
        with torch.no_grad():
            table = self.interpolate_pos_encoding(*grid).detach().clone()
        self._frozen_pos = (grid, table)

    def prepare_tokens(self, x: torch.Tensor) -> torch.Tensor:
        """Image [B,3,H,W] -> tokens [B, 1 + R + N, D] with positional embedding added."""
        self.check_input(x)
        h, w = x.shape[-2:]
        tokens = self.patch_embed(x)
        tokens = torch.cat((self.cls_token.expand(tokens.shape[0], -1, -1), tokens), dim=1)
        pos = self.interpolate_pos_encoding(h // self.patch_size, w // self.patch_size)
        tokens = tokens + pos.to(tokens.dtype)
        if self.register_tokens is not None:
            regs = self.register_tokens.expand(tokens.shape[0], -1, -1).to(tokens.dtype)
            tokens = torch.cat((tokens[:, :1], regs, tokens[:, 1:]), dim=1)
        return tokens

"""DINOv3 vision transformer in plain PyTorch, key-compatible with the official checkpoints.

The trunk (blocks, checks, ``get_intermediate_layers``) is `claravid.models.backbones.trunk`'s,
shared with
DINOv2. Parameter names follow ``facebookresearch/dinov3`` (``storage_tokens``,
``rope_embed.periods``, ``blocks.N.attn.qkv.bias_mask``, ``ls1.gamma``, ``mlp.w1/w2/w3`` ...) so
an official ``.pth`` loads with a strict ``load_state_dict``. What differs from DINOv2
(`claravid.models.backbones.dinov2`):

- patches of 16 pixels and no learned positional embedding: queries and keys of the patch
  tokens are rotated by RoPE (`claravid.models.layers.rope`), so any grid works without resizing a
  table;
- tokens [CLS, 4 storage tokens, patches] (storage tokens are DINOv2's registers);
- the key bias is masked out: ``qkv`` has one bias of 3D values, multiplied by the persistent
  buffer ``bias_mask`` (1 for q, 0 for k, 1 for v) — the 7B model has no qkv bias at all;
- LayerNorm eps 1e-5; SwiGLU feed-forwards with three matrices (w1, w2, w3) in S+, H+ and 7B.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from claravid.models.backbones.trunk import VisionTransformer
from claravid.models.layers.attention import Attention
from claravid.models.layers.blocks import Mlp, SwiGLU, swiglu_hidden
from claravid.models.layers.rope import RopePositionEmbedding


class DinoV3VisionTransformer(VisionTransformer):
    """DINOv3 ViT backbone.

    The official sizes' arguments are in `claravid.models.backbones.specs` (``build_backbone``).

    Args:
        embed_dim: Token width D.
        depth: Number of blocks.
        num_heads: Attention heads (D / heads must be a multiple of 4).
        patch_size: Patch side in pixels (16 in the official models).
        mean: Per-channel input mean (RGB, pixels in [0, 1]) of the weights' training data.
        std: Per-channel input std.
        ffn: ``"mlp"`` (GELU MLP, fc1/fc2) or ``"swiglu"`` (w1/w2/w3).
        ffn_ratio: Feed-forward expansion (4 MLP; 6 for S+/H+ and 3 for 7B SwiGLU).
        swiglu_align: SwiGLU hidden width rounded up to a multiple of it (8; 64 for 7B).
        qkv_bias: Bias on the q/k/v projection (all but 7B).
        num_storage_tokens: Extra learned tokens after CLS, without position (4).
        rope_base: RoPE period base (100).
        rope_dtype: The dtype RoPE was trained in, ``"bf16"`` (the distilled models: their
            files hold periods rounded to bfloat16) or ``"fp32"`` (7B). It sets the periods of
            a model built without weights and of files that carry none (Hugging Face, timm);
            an official file's own periods replace them.
        norm_eps: LayerNorm epsilon (1e-5).
        local_cls_norm: Hold the pre-training-only ``local_cls_norm`` LayerNorm (never applied)
            that the SAT-493M ViT-L and the 7B files contain, so they load strictly.
    """

    def __init__(
        self,
        *,
        embed_dim: int,
        depth: int,
        num_heads: int,
        patch_size: int,
        mean: Sequence[float],
        std: Sequence[float],
        ffn: str = "mlp",
        ffn_ratio: float = 4.0,
        swiglu_align: int = 8,
        qkv_bias: bool = True,
        num_storage_tokens: int = 4,
        rope_base: float = 100.0,
        rope_dtype: str = "fp32",
        norm_eps: float = 1e-5,
        local_cls_norm: bool = False,
    ) -> None:
        if embed_dim % num_heads or (embed_dim // num_heads) % 4:
            raise ValueError(
                f"embed_dim {embed_dim} / num_heads {num_heads} must be a whole multiple of 4 "
                "(RoPE rotates pairs of y and x channels)"
            )
        super().__init__(
            embed_dim=embed_dim,
            depth=depth,
            num_heads=num_heads,
            patch_size=patch_size,
            mean=mean,
            std=std,
        )
        self.num_storage_tokens = num_storage_tokens
        if num_storage_tokens:
            self.storage_tokens: nn.Parameter | None = nn.Parameter(
                torch.zeros(1, num_storage_tokens, embed_dim)
            )
        else:
            self.storage_tokens = None
        self.rope_embed = RopePositionEmbedding(embed_dim // num_heads, rope_base, rope_dtype)
        if ffn == "mlp":
            hidden = int(embed_dim * ffn_ratio)
        elif ffn == "swiglu":
            hidden = swiglu_hidden(embed_dim, ffn_ratio, swiglu_align)
        else:
            raise ValueError(f"unknown ffn {ffn!r}: use 'mlp' or 'swiglu'")
        feed_forward = Mlp if ffn == "mlp" else SwiGLU
        prefix = 1 + num_storage_tokens
        self._add_blocks(
            lambda: Attention(embed_dim, num_heads, qkv_bias, True, prefix),
            lambda: feed_forward(embed_dim, hidden),
            norm_eps,
        )
        self.local_cls_norm = nn.LayerNorm(embed_dim, eps=norm_eps) if local_cls_norm else None
        self._init_weights()

    def _init_weights(self) -> None:
        nn.init.normal_(self.cls_token, std=0.02)
        if self.storage_tokens is not None:
            nn.init.normal_(self.storage_tokens, std=0.02)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

    @property
    def num_prefix_tokens(self) -> int:
        """CLS plus storage tokens, ahead of the patch tokens."""
        return 1 + self.num_storage_tokens

    def freeze_pos_embed(self, height: int | None, width: int | None = None) -> None:
        """Precompute the RoPE sin/cos for one input size (``None`` clears them).

        The DINOv2 counterpart stores an interpolated positional table for a fixed-size ONNX
        export; here there is no table, but storing the rotation angles lets that export hold
        them as constants. Other sizes are still computed, with the same values.
        """
        if height is None:
            self.rope_embed.freeze(None)
            return
        width = height if width is None else width
        self.check_input_size(height, width)
        self.rope_embed.freeze(height // self.patch_size, width // self.patch_size)

    def prepare_tokens(self, x: torch.Tensor) -> torch.Tensor:
        """Image [B,3,H,W] -> tokens [B, 1 + storage + N, D] (no positional term: see RoPE)."""
        self.check_input(x)
        tokens = self.patch_embed(x)
        b = tokens.shape[0]
        prefix = [self.cls_token.expand(b, -1, -1)]
        if self.storage_tokens is not None:
            prefix.append(self.storage_tokens.expand(b, -1, -1))
        return torch.cat([*(t.to(tokens.dtype) for t in prefix), tokens], dim=1)

    def positions(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """RoPE's (sin, cos) of the patch grid of ``x``, handed to every block."""
        h, w = x.shape[-2:]
        return self.rope_embed(h // self.patch_size, w // self.patch_size)

"""DINOv2 weights as data: the Hugging Face and timm names of the official tensors.

Official ``.pth`` files carry our names. The other formats, declared below for
`claravid.models.weights.formats`:

- Hugging Face ``Dinov2Model`` / ``Dinov2WithRegistersModel`` (``facebook/dinov2-*``):
  ``embeddings.*`` and ``encoder.layer.N.*``, separate query/key/value projections (in files
  ``attention.attention.query``; in transformers 5's memory ``attention.q_proj``); task models
  (``Dinov2ForImageClassification``) keep the backbone under ``dinov2.``.
- timm (``timm/vit_*_patch14_dinov2.lvd142m``, ``…_reg4_dinov2.lvd142m``): the official names
  without the mask token, the giant model's SwiGLU as ``mlp.fc1``/``mlp.fc2``, and with
  registers ``reg_token`` and the CLS position folded into the token (``cls_token + pos_embed[0]``,
  the table keeping the patch positions only). Reading one back puts a zero CLS position in the
  table: the sum the model adds is the same.

Hugging Face's own models resize the positional table in another way than the official code at
sizes other than 518 (docs/models.md); this toolkit keeps the official rule for every format.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from claravid.models.weights.formats import (
    KeyFormat,
    Rename,
    Split,
    State,
    WeightsFamily,
)

_LAYER = "encoder.layer.{n}"

HUGGING_FACE = KeyFormat(
    name="Hugging Face",
    has=r"(dinov2\.)?(embeddings\..*|encoder\.layer\..*)",
    renames=(
        Rename("cls_token", "embeddings.cls_token"),
        Rename("mask_token", "embeddings.mask_token"),
        Rename("pos_embed", "embeddings.position_embeddings"),
        Rename("register_tokens", "embeddings.register_tokens"),
        Rename("patch_embed.proj.{p}", "embeddings.patch_embeddings.projection.{p}"),
        Rename("norm.{p}", "layernorm.{p}"),
        Rename("blocks.{n}.norm1.{p}", f"{_LAYER}.norm1.{{p}}"),
        Rename("blocks.{n}.norm2.{p}", f"{_LAYER}.norm2.{{p}}"),
        Rename("blocks.{n}.ls1.gamma", f"{_LAYER}.layer_scale1.lambda1"),
        Rename("blocks.{n}.ls2.gamma", f"{_LAYER}.layer_scale2.lambda1"),
        Rename("blocks.{n}.attn.proj.{p}", f"{_LAYER}.attention.output.dense.{{p}}"),
        # transformers 5 names its modules so in memory (its files keep the names above).
        Rename("blocks.{n}.attn.proj.{p}", f"{_LAYER}.attention.o_proj.{{p}}"),
        Rename("blocks.{n}.mlp.fc1.{p}", f"{_LAYER}.mlp.fc1.{{p}}", ffn="mlp"),
        Rename("blocks.{n}.mlp.fc2.{p}", f"{_LAYER}.mlp.fc2.{{p}}", ffn="mlp"),
        Rename("blocks.{n}.mlp.w12.{p}", f"{_LAYER}.mlp.weights_in.{{p}}", ffn="swiglu"),
        Rename("blocks.{n}.mlp.w3.{p}", f"{_LAYER}.mlp.weights_out.{{p}}", ffn="swiglu"),
    ),
    splits=(
        Split(
            "blocks.{n}.attn.qkv.{p}",
            tuple(f"{_LAYER}.attention.attention.{x}.{{p}}" for x in ("query", "key", "value")),
        ),
        Split(
            "blocks.{n}.attn.qkv.{p}", tuple(f"{_LAYER}.attention.{x}_proj.{{p}}" for x in "qkv")
        ),
    ),
    within=("dinov2.",),
    gated=lambda state: any(".mlp.weights_in." in k for k in state),
)


def _unfold_cls_position(state: State) -> State:
    """timm's register models: the table holds patch positions only -> a zero CLS row first."""
    pos = state.get("pos_embed")
    if (
        pos is not None
        and "register_tokens" in state
        and math.isqrt(pos.shape[1]) ** 2 == pos.shape[1]
    ):
        state["pos_embed"] = torch.cat([torch.zeros_like(pos[:, :1]), pos], dim=1)
    return state


def _fold_cls_position(state: State) -> State:
    """The official register models -> timm's: CLS position added into the token."""
    if "register_tokens" in state and "pos_embed" in state:
        pos = state["pos_embed"]
        state["cls_token"] = state["cls_token"] + pos[:, :1]
        state["pos_embed"] = pos[:, 1:]
    return state


def _timm_gated(state: Mapping[str, torch.Tensor]) -> bool:
    """timm names the giant model's fused SwiGLU fc1/fc2 like an MLP: fc1 is then twice as wide
    as fc2's input (the two halves of w12), where an MLP's are equal."""
    fc1, fc2 = state.get("blocks.0.mlp.fc1.weight"), state.get("blocks.0.mlp.fc2.weight")
    return fc1 is not None and fc2 is not None and fc1.shape[0] == 2 * fc2.shape[1]


TIMM = KeyFormat(
    name="timm",
    # timm keeps the official names but drops the (pre-training only) mask token.
    has=r"pos_embed|reg_token",
    lacks=r"mask_token",
    renames=(
        Rename("register_tokens", "reg_token"),
        Rename("blocks.{n}.mlp.w12.{p}", "blocks.{n}.mlp.fc1.{p}", ffn="swiglu"),
        Rename("blocks.{n}.mlp.w3.{p}", "blocks.{n}.mlp.fc2.{p}", ffn="swiglu"),
    ),
    absent=(r"mask_token",),
    gated=_timm_gated,
    to_official=_unfold_cls_position,
    from_official=_fold_cls_position,
)

DINOV2 = WeightsFamily(
    family="dinov2",
    marker=(
        r"(dinov2\.)?(pos_embed|embeddings\.position_embeddings|encoder\.layer\..*"
        r"|blocks\.\d+\.mlp\.w12\..*)"
    ),
    formats=(HUGGING_FACE, TIMM),
    model_types=("dinov2", "dinov2_with_registers"),
    # transformers' Dinov2Config / Dinov2WithRegistersConfig fields.
    hf_config={
        "hidden_size": lambda a: a["embed_dim"],
        "num_hidden_layers": lambda a: a["depth"],
        "num_attention_heads": lambda a: a["num_heads"],
        "mlp_ratio": lambda a: a["mlp_ratio"],
        "patch_size": lambda a: a["patch_size"],
        "image_size": lambda a: a["img_size"],
        "use_swiglu_ffn": lambda a: a["ffn"] == "swiglu",
        "num_register_tokens": lambda a: a["num_register_tokens"],
        "hidden_act": lambda a: "gelu",
        "layer_norm_eps": lambda a: 1e-6,
    },
)

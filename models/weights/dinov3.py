"""DINOv3 weights as data: the Hugging Face and timm names of the official tensors, and the checks
only DINOv3 files need (the key-bias mask; the RoPE periods through
`claravid.models.layers.rope.check_periods`).

Official ``.pth`` files carry our names. The other formats, declared below for
`claravid.models.weights.formats`:

- Hugging Face ``DINOv3ViTModel`` (``model.safetensors`` of ``facebook/dinov3-*``): separate
  ``q_proj``/``k_proj``/``v_proj`` (no key bias: it is the masked one), the mask token as
  [1, 1, D], ``layer.N`` (``model.layer.N`` in newer transformers); no RoPE periods, bias masks
  or ``local_cls_norm``.
- timm (``timm/vit_*_patch16_dinov3*``, ``model.safetensors``): the official names except
  ``reg_token`` for the storage tokens, ``gamma_1``/``gamma_2`` for the LayerScales, the q and v
  biases as ``q_bias``/``v_bias`` (``_qkvb`` variants; the plain ones drop the all-zero bias of
  B, L and H+), SwiGLU ``fc1_g``/``fc1_x``/``fc2``; no periods, bias masks, mask token or
  ``local_cls_norm``.

What a format does not store is taken from the model as built: in particular the RoPE periods
that the released official file of that model holds (bfloat16-rounded for the distilled models,
float32 for 7B: `claravid.models.layers.rope`), so the three formats of one checkpoint give the same
features.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import nn

from claravid.models.layers.blocks import swiglu_hidden
from claravid.models.layers.rope import check_periods as rope_check_periods
from claravid.models.weights.formats import KeyFormat, Rename, Split, WeightsError, WeightsFamily

_BLOCK_NORMS = tuple(
    Rename(f"blocks.{{n}}.{norm}.{{p}}", f"layer.{{n}}.{norm}.{{p}}") for norm in ("norm1", "norm2")
)

HUGGING_FACE = KeyFormat(
    name="Hugging Face",
    has=r"(model\.)?(embeddings\..*|layer\.\d+\..*)",
    renames=(
        Rename("cls_token", "embeddings.cls_token"),
        Rename("mask_token", "embeddings.mask_token"),
        Rename("storage_tokens", "embeddings.register_tokens"),
        Rename("patch_embed.proj.{p}", "embeddings.patch_embeddings.{p}"),
        *_BLOCK_NORMS,
        Rename("blocks.{n}.ls1.gamma", "layer.{n}.layer_scale1.lambda1"),
        Rename("blocks.{n}.ls2.gamma", "layer.{n}.layer_scale2.lambda1"),
        Rename("blocks.{n}.attn.proj.{p}", "layer.{n}.attention.o_proj.{p}"),
        Rename("blocks.{n}.mlp.fc1.{p}", "layer.{n}.mlp.up_proj.{p}", ffn="mlp"),
        Rename("blocks.{n}.mlp.fc2.{p}", "layer.{n}.mlp.down_proj.{p}", ffn="mlp"),
        Rename("blocks.{n}.mlp.w1.{p}", "layer.{n}.mlp.gate_proj.{p}", ffn="swiglu"),
        Rename("blocks.{n}.mlp.w2.{p}", "layer.{n}.mlp.up_proj.{p}", ffn="swiglu"),
        Rename("blocks.{n}.mlp.w3.{p}", "layer.{n}.mlp.down_proj.{p}", ffn="swiglu"),
    ),
    splits=(
        Split(
            "blocks.{n}.attn.qkv.weight",
            tuple(f"layer.{{n}}.attention.{x}_proj.weight" for x in "qkv"),
        ),
        Split(
            "blocks.{n}.attn.qkv.bias",
            ("layer.{n}.attention.q_proj.bias", None, "layer.{n}.attention.v_proj.bias"),
        ),
    ),
    absent=(r"rope_embed\.periods", r"blocks\.\d+\.attn\.qkv\.bias_mask", r"local_cls_norm\..*"),
    strip=("model.",),
    reshape=("mask_token",),
    gated=lambda state: any(".mlp.gate_proj." in k for k in state),
)

TIMM = KeyFormat(
    name="timm",
    has=r"reg_token|blocks\.\d+\.gamma_1|blocks\.\d+\.attn\.[qv]_bias",
    renames=(
        Rename("storage_tokens", "reg_token"),
        Rename("blocks.{n}.ls1.gamma", "blocks.{n}.gamma_1"),
        Rename("blocks.{n}.ls2.gamma", "blocks.{n}.gamma_2"),
        Rename("blocks.{n}.mlp.w1.{p}", "blocks.{n}.mlp.fc1_g.{p}", ffn="swiglu"),
        Rename("blocks.{n}.mlp.w2.{p}", "blocks.{n}.mlp.fc1_x.{p}", ffn="swiglu"),
        Rename("blocks.{n}.mlp.w3.{p}", "blocks.{n}.mlp.fc2.{p}", ffn="swiglu"),
    ),
    splits=(
        Split(
            "blocks.{n}.attn.qkv.bias", ("blocks.{n}.attn.q_bias", None, "blocks.{n}.attn.v_bias")
        ),
    ),
    # The plain (not _qkvb) variants drop the qkv bias, all zero in B, L and H+.
    absent=(
        r"rope_embed\.periods",
        r"blocks\.\d+\.attn\.qkv\.bias(_mask)?",
        r"mask_token",
        r"local_cls_norm\..*",
    ),
    gated=lambda state: any(".mlp.fc1_g." in k for k in state),
)


def check_periods(state: dict[str, torch.Tensor], model: nn.Module, source: str) -> None:
    """Refuse ``rope_embed.periods`` of another RoPE base than the model's
    (`claravid.models.layers.rope.check_periods`)."""
    periods = state.get("rope_embed.periods")
    rope = getattr(model, "rope_embed", None)
    if periods is None or rope is None:
        return
    try:
        rope_check_periods(periods, rope.head_dim, rope.base)
    except ValueError as error:
        raise WeightsError(
            f"{source}: {error}: the file was trained with other RoPE settings than the "
            "official DINOv3 models; pass an official DINOv3 file"
        ) from None


def check_bias_masks(state: dict[str, torch.Tensor], source: str) -> None:
    """Refuse a ``bias_mask`` that is not 1 (q), 0 (k), 1 (v): it multiplies the bias, and any
    other value (a NaN, a damaged file) would change or poison every feature."""
    for key in sorted(k for k in state if k.endswith(".attn.qkv.bias_mask")):
        mask = state[key]
        d = mask.shape[0] // 3
        want = torch.ones_like(mask, dtype=torch.float32)
        want[d : 2 * d] = 0
        if mask.shape[0] % 3 or not torch.equal(mask.float(), want):
            raise WeightsError(
                f"{source}: {key} is not 1 for the query, 0 for the key and 1 for the value "
                f"part (it holds {_values(mask)}): the file is damaged or not an official DINOv3 "
                "file; download it again"
            )


def _values(t: torch.Tensor) -> str:
    values = sorted({str(v) for v in t.float().unique().tolist()})
    return ", ".join(values[:5])


def _checks(state: dict[str, torch.Tensor], model: nn.Module, source: str) -> None:
    check_bias_masks(state, source)
    check_periods(state, model, source)


def _hidden(arch: Mapping[str, Any]) -> int:
    if arch["ffn"] == "swiglu":
        return swiglu_hidden(arch["embed_dim"], arch["ffn_ratio"], arch["swiglu_align"])
    return int(arch["embed_dim"] * arch["ffn_ratio"])


DINOV3 = WeightsFamily(
    family="dinov3",
    marker=(
        r"(model\.)?(storage_tokens|rope_embed\.periods|local_cls_norm\..*"
        r"|blocks\.\d+\.attn\.qkv\.bias_mask|layer\.\d+\..*"
        r"|blocks\.\d+\.gamma_1|blocks\.\d+\.attn\.[qv]_bias)"
    ),
    formats=(HUGGING_FACE, TIMM),
    model_types=("dinov3_vit",),
    # transformers' DINOv3ViTConfig fields that must agree with the architecture.
    hf_config={
        "hidden_size": lambda a: a["embed_dim"],
        "num_hidden_layers": lambda a: a["depth"],
        "num_attention_heads": lambda a: a["num_heads"],
        "intermediate_size": _hidden,
        "patch_size": lambda a: a["patch_size"],
        "num_register_tokens": lambda a: a["num_storage_tokens"],
        "rope_theta": lambda a: a["rope_base"],
        "hidden_act": lambda a: "silu" if a["ffn"] == "swiglu" else "gelu",
        "use_gated_mlp": lambda a: a["ffn"] == "swiglu",
        "layer_norm_eps": lambda a: a["norm_eps"],
        "query_bias": lambda a: a["qkv_bias"],
        "value_bias": lambda a: a["qkv_bias"],
    },
    check=_checks,
)

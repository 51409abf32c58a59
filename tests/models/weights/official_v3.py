"""DINOv3 test material written from the official formats, not from the code under test.

- `random_official_v3_state`: random values in the official ``.pth`` key layout, with the
  buffers the official files hold set by hand (``bias_mask`` 1/0/1, ``rope_embed.periods``
  ``100 ** (2k / (d/2))``) and LayerScale gammas drawn in [0.5, 1.5] (the official 1e-5 init
  would make every block nearly the identity, and a wrong block would go unnoticed).
- `released_v3_state`: the same, made as Meta's released files were: the official model built
  with its RoPE dtype set to bfloat16 (the distilled models' training setting) stores periods
  computed in bfloat16, as a bfloat16 tensor; 7B keeps float32. The distilled ViT-B, L and H+
  also have an all-zero qkv bias.
- `to_hugging_face`: the same tensors under transformers' ``DINOv3ViTModel`` names, by a plain
  rename written out here (q/k/v split by rows; no key bias; mask token [1, 1, D]; no periods,
  bias masks or ``local_cls_norm``).
- `to_timm`: the same tensors as timm's DINOv3 files hold them, by timm's own key mapping
  (``checkpoint_filter_fn`` of ``timm/models/eva.py``) written out here.
"""

from __future__ import annotations

import re

import torch


def random_official_v3_state(model: torch.nn.Module, seed: int = 0) -> dict[str, torch.Tensor]:
    """Random official-layout values for every key of ``model``'s state dict."""
    g = torch.Generator().manual_seed(seed)
    state = {}
    for key, value in model.state_dict().items():
        shape = value.shape
        if key.endswith("attn.qkv.bias_mask"):
            d = shape[0] // 3
            state[key] = torch.cat([torch.ones(d), torch.zeros(d), torch.ones(d)])
        elif key == "rope_embed.periods":
            quarter = shape[0]  # head_dim / 4
            state[key] = torch.tensor([100.0 ** (2 * k / (2 * quarter)) for k in range(quarter)])
        elif key.endswith(("ls1.gamma", "ls2.gamma")):
            state[key] = 0.5 + torch.rand(shape, generator=g)
        elif key.endswith(".weight") and "norm" in key:
            state[key] = 1.0 + 0.1 * torch.randn(shape, generator=g)
        elif key in ("cls_token", "storage_tokens", "mask_token"):
            state[key] = torch.randn(shape, generator=g)
        else:
            scale = 0.2 if len(shape) > 1 else 0.05
            state[key] = scale * torch.randn(shape, generator=g)
    return state


#: The backbones whose released files have an all-zero qkv bias (the distilled B, L and H+).
ZERO_QKV_BIAS = ("dinov3_vitb16", "dinov3_vitl16", "dinov3_vitl16_sat", "dinov3_vith16plus")


def official_periods(quarter: int, dtype: torch.dtype, base: float = 100.0) -> torch.Tensor:
    """``rope_embed.periods`` as the official ``RopePositionEmbedding`` initialises them with
    ``dtype``: the whole formula evaluated in that dtype, stored in it."""
    return base ** (2 * torch.arange(quarter, dtype=dtype) / (2 * quarter))


def released_v3_state(model: torch.nn.Module, name: str, seed: int = 0) -> dict[str, torch.Tensor]:
    """A released-style official state of backbone ``name`` (bfloat16 periods, but 7B)."""
    state = random_official_v3_state(model, seed)
    dtype = torch.float32 if name.startswith("dinov3_vit7b16") else torch.bfloat16
    state["rope_embed.periods"] = official_periods(state["rope_embed.periods"].shape[0], dtype)
    if name in ZERO_QKV_BIAS:
        for key in state:
            if key.endswith("attn.qkv.bias"):
                state[key] = torch.zeros_like(state[key])
    return state


def to_hugging_face(state: dict[str, torch.Tensor], prefix: str = "") -> dict[str, torch.Tensor]:
    """Official DINOv3 keys -> transformers ``DINOv3ViTModel`` keys.

    ``prefix`` goes before ``layer.`` (``"model."`` in transformers 5, ``""`` in 4.57).
    """
    gated = any(".mlp.w1." in k for k in state)
    ffn = {"w1": "gate_proj", "w2": "up_proj", "w3": "down_proj", "fc1": "up_proj",
           "fc2": "down_proj"}  # fmt: skip
    top = {
        "cls_token": "embeddings.cls_token",
        "storage_tokens": "embeddings.register_tokens",
        "patch_embed.proj.weight": "embeddings.patch_embeddings.weight",
        "patch_embed.proj.bias": "embeddings.patch_embeddings.bias",
        "norm.weight": "norm.weight",
        "norm.bias": "norm.bias",
    }
    out = {}
    for key, value in state.items():
        if key in top:
            out[top[key]] = value.clone()
        elif key == "mask_token":
            out["embeddings.mask_token"] = value.reshape(1, 1, -1).clone()
        elif key == "rope_embed.periods" or key.startswith("local_cls_norm."):
            continue  # not stored by transformers
        else:
            i, rest = re.fullmatch(r"blocks\.(\d+)\.(.+)", key).groups()
            layer = f"{prefix}layer.{i}."
            d = value.shape[0] // 3
            if rest == "attn.qkv.weight":
                q, k, v = value[:d], value[d : 2 * d], value[2 * d :]
                out[layer + "attention.q_proj.weight"] = q.clone()
                out[layer + "attention.k_proj.weight"] = k.clone()
                out[layer + "attention.v_proj.weight"] = v.clone()
            elif rest == "attn.qkv.bias":
                out[layer + "attention.q_proj.bias"] = value[:d].clone()
                out[layer + "attention.v_proj.bias"] = value[2 * d :].clone()
            elif rest == "attn.qkv.bias_mask":
                continue
            elif rest.startswith("attn.proj."):
                out[layer + "attention.o_proj." + rest.split(".")[-1]] = value.clone()
            elif rest in ("ls1.gamma", "ls2.gamma"):
                out[layer + f"layer_scale{rest[2]}.lambda1"] = value.clone()
            elif rest.startswith(("norm1.", "norm2.")):
                out[layer + rest] = value.clone()
            else:
                _, name, kind = rest.split(".")  # mlp.<name>.<weight|bias>
                assert gated == name.startswith("w"), key
                out[layer + f"mlp.{ffn[name]}.{kind}"] = value.clone()
    return out


def to_timm(state: dict[str, torch.Tensor], qkvb: bool = True) -> dict[str, torch.Tensor]:
    """Official DINOv3 keys -> timm's (``vit_*_patch16_dinov3[_qkvb]``).

    Dropped: the periods, bias masks, mask token and ``local_cls_norm``; the qkv bias becomes
    ``q_bias`` and ``v_bias`` (first and last thirds) in the ``_qkvb`` variants and is dropped in
    the plain ones; ``storage_tokens`` -> ``reg_token``; ``ls1/ls2.gamma`` -> ``gamma_1/2``;
    SwiGLU ``w1, w2, w3`` -> ``fc1_g, fc1_x, fc2``.
    """
    swiglu = {"w1": "fc1_g", "w2": "fc1_x", "w3": "fc2"}
    out = {}
    for key, value in state.items():
        if key in ("rope_embed.periods", "mask_token") or key.startswith("local_cls_norm."):
            continue
        if key.endswith(".bias_mask"):
            continue
        if key.endswith("attn.qkv.bias"):
            if qkvb:
                d = value.shape[0] // 3
                out[key.replace("qkv.bias", "q_bias")] = value[:d].clone()
                out[key.replace("qkv.bias", "v_bias")] = value[2 * d :].clone()
            continue
        key = key.replace("storage_tokens", "reg_token")
        key = key.replace(".ls1.gamma", ".gamma_1").replace(".ls2.gamma", ".gamma_2")
        m = re.fullmatch(r"(blocks\.\d+\.mlp\.)(w[123])(\..+)", key)
        if m is not None:
            key = m.group(1) + swiglu[m.group(2)] + m.group(3)
        out[key] = value.clone()
    return out

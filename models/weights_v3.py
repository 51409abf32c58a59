"""DINOv3 weights: Hugging Face names, and the checks that say which backbone a file is for.

An official ``.pth`` has our keys already. A Hugging Face ``DINOv3ViTModel``
``model.safetensors`` is renamed key by key (``layer.N`` or, in newer transformers,
``model.layer.N``):

- its separate ``q_proj``/``k_proj``/``v_proj`` are concatenated into ``qkv`` (rows q, k, v),
  with a zero key bias where the file has none (the official models mask it out anyway);
- ``embeddings.mask_token`` [1, 1, D] becomes ``mask_token`` [1, D];
- what transformers does not store is taken from the model: ``rope_embed.periods`` (those the
  released official file of that model holds: rounded to bfloat16 for the distilled models,
  float32 for 7B), ``bias_mask`` (1 for q, 0 for k, 1 for v) and the unused ``local_cls_norm``.

Which file for which backbone: the official file names end with a hash
(``-eadcf0ff`` is the SAT-493M ViT-L, ``-8aa4cbdd`` the LVD-1689M ViT-L ...), and among the ViT-L
files only the SAT-493M one holds ``local_cls_norm.*``. A file that shows it belongs to another
backbone is refused with that backbone's name, because web and satellite weights have the same
shapes and would load silently with the wrong input statistics.
"""

from __future__ import annotations

import re
from pathlib import Path

import torch
from torch import nn

from claravid.models.backbones import BACKBONES, BackboneSpec, spec_for_hash
from claravid.models.rope import rope_periods
from claravid.models.weights import WeightsError

_HF_TOP = {
    "embeddings.cls_token": "cls_token",
    "embeddings.mask_token": "mask_token",
    "embeddings.register_tokens": "storage_tokens",
    "embeddings.patch_embeddings.weight": "patch_embed.proj.weight",
    "embeddings.patch_embeddings.bias": "patch_embed.proj.bias",
    "norm.weight": "norm.weight",
    "norm.bias": "norm.bias",
}
_HF_BLOCK = {
    "layer_scale1.lambda1": "ls1.gamma",
    "layer_scale2.lambda1": "ls2.gamma",
    **{f"{n}.{p}": f"{n}.{p}" for n in ("norm1", "norm2") for p in ("weight", "bias")},
    **{f"attention.o_proj.{p}": f"attn.proj.{p}" for p in ("weight", "bias")},
}
# Feed-forward names: the plain MLP (up, down) and the gated one (gate = w1, up = w2, down = w3).
_HF_MLP = {"up_proj": "fc1", "down_proj": "fc2"}
_HF_SWIGLU = {"gate_proj": "w1", "up_proj": "w2", "down_proj": "w3"}
_QKV = ("q_proj", "k_proj", "v_proj")


def is_hf_dinov3(state: dict[str, torch.Tensor]) -> bool:
    """True when the keys are Hugging Face ``DINOv3ViTModel`` names (either spelling)."""
    return any(k.startswith(("embeddings.", "layer.", "model.")) for k in state)


def dinov3_hf_to_official(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Rename a Hugging Face DINOv3 state dict to official keys (q/k/v concatenated).

    Accepts both spellings (``layer.N`` and ``model.layer.N``, ``model.`` before anything).
    Tensors transformers does not store (RoPE periods, bias mask, ``local_cls_norm``) are not
    added here. Keys that match no rule are kept unchanged, so the strict load reports them.
    """
    state = {k.removeprefix("model."): v for k, v in state.items()}
    gated = any(re.fullmatch(r"layer\.\d+\.mlp\.gate_proj\..*", k) for k in state)
    mlp = _HF_SWIGLU if gated else _HF_MLP
    out: dict[str, torch.Tensor] = {}
    qkv: dict[tuple[str, str], dict[str, torch.Tensor]] = {}
    for key, value in state.items():
        if key in _HF_TOP:
            # transformers keeps the mask token as [1, 1, D], the official code as [1, D].
            out[_HF_TOP[key]] = value.reshape(1, -1) if key.endswith("mask_token") else value
            continue
        m = re.fullmatch(r"layer\.(\d+)\.(.+)", key)
        if m is None:
            out[key] = value
            continue
        idx, inner = m.groups()
        am = re.fullmatch(r"attention\.([qkv]_proj)\.(weight|bias)", inner)
        fm = re.fullmatch(r"mlp\.(\w+)\.(weight|bias)", inner)
        if am is not None:
            qkv.setdefault((idx, am.group(2)), {})[am.group(1)] = value
        elif inner in _HF_BLOCK:
            out[f"blocks.{idx}.{_HF_BLOCK[inner]}"] = value
        elif fm is not None and fm.group(1) in mlp:
            out[f"blocks.{idx}.mlp.{mlp[fm.group(1)]}.{fm.group(2)}"] = value
        else:
            out[key] = value
    for (idx, kind), parts in sorted(qkv.items()):
        if kind == "bias" and "k_proj" not in parts and "q_proj" in parts:
            parts["k_proj"] = torch.zeros_like(parts["q_proj"])  # transformers has no key bias
        missing = sorted(set(_QKV) - set(parts))
        if missing:
            raise WeightsError(
                f"Hugging Face layer {idx}: attention {kind} lacks {missing}; "
                "the file is incomplete, download it again"
            )
        out[f"blocks.{idx}.attn.qkv.{kind}"] = torch.cat([parts[n] for n in _QKV], dim=0)
    return out


def _fill_from_model(state: dict[str, torch.Tensor], model: nn.Module) -> None:
    """Add what a Hugging Face file lacks and the model derives: the periods the released
    official file holds (rounded through the dtype the model was trained with), bias masks, and
    the pre-training-only ``local_cls_norm`` (never used)."""
    own = model.state_dict()
    rope = getattr(model, "rope_embed", None)
    for key, value in own.items():
        derived = key.startswith("local_cls_norm.")
        if key.endswith(".attn.qkv.bias_mask"):
            derived = key.removesuffix("_mask") in state  # only where the file has the bias
        if derived and key not in state:
            state[key] = value.detach().clone()
    if rope is not None and "rope_embed.periods" not in state:
        state["rope_embed.periods"] = rope_periods(rope.head_dim, rope.base, rope.dtype)


def check_file_name(path: Path, spec: BackboneSpec) -> None:
    """Refuse an official DINOv3 file (named with its hash) given to another backbone."""
    match = re.search(r"-([0-9a-f]{8})\.[A-Za-z]+$", path.name)
    owner = spec_for_hash(match.group(1)) if match else None
    if owner is None or owner.name == spec.name:
        return
    raise WeightsError(
        f"{path} is the official file of {owner.name} ({owner.weights.dataset}, hash "
        f"-{owner.weights.hash}), not of {spec.name} ({spec.weights.dataset}): build "
        f"{owner.name} for it (inputs normalised with mean {owner.mean}, std {owner.std})"
    )


def check_local_cls_norm(state: dict[str, torch.Tensor], spec: BackboneSpec, source: str) -> None:
    """Refuse an official file whose ``local_cls_norm.*`` keys show it is another backbone's.

    Among same-shaped backbones (ViT-L web and satellite) only the SAT-493M file holds them.
    """
    has = any(k.startswith("local_cls_norm.") for k in state)
    if has == bool(spec.arch["local_cls_norm"]):
        return
    shape = ("embed_dim", "depth", "num_heads", "ffn", "ffn_ratio")
    sibling = next(
        (
            other
            for other in BACKBONES.values()
            if other.family == spec.family
            and bool(other.arch["local_cls_norm"]) == has
            and all(other.arch[k] == spec.arch[k] for k in shape)
        ),
        None,
    )
    if sibling is None:
        return  # the strict load lists the keys
    holds = "holds" if has else "lacks"
    raise WeightsError(
        f"{source} {holds} local_cls_norm.*, so it is the {sibling.weights.dataset} file of "
        f"{sibling.name} ({sibling.weights.file}), not a {spec.weights.dataset} file for "
        f"{spec.name}: build {sibling.name} for it"
    )


#: How far stored periods may lie from the formula: one bfloat16 step (8 significant bits), so
#: the released files (periods rounded to bfloat16) and state dicts saved in float16 or bfloat16
#: pass, while periods of another base (or of minimum/maximum periods) do not.
PERIODS_RTOL = 2.0**-7


def check_periods(state: dict[str, torch.Tensor], model: nn.Module, source: str) -> None:
    """Refuse ``rope_embed.periods`` of another RoPE base than the model's.

    Values within a bfloat16 rounding (`PERIODS_RTOL`) of ``base ** (2k / (d/2))`` pass: the
    loaded values are then the ones the model uses, as in the official code.
    """
    periods = state.get("rope_embed.periods")
    rope = getattr(model, "rope_embed", None)
    if periods is None or rope is None:
        return
    expected = rope_periods(rope.head_dim, rope.base)
    if periods.shape != expected.shape:
        return  # the strict load reports the shape
    got = periods.float()
    if bool(((got - expected).abs() <= PERIODS_RTOL * expected).all()):
        return
    fit = ""
    if len(got) > 1 and bool(got[-1] > 0):
        # periods[k] = base ** (4k / d): the last one tells the base.
        base = float(got[-1]) ** (rope.head_dim / (4 * (len(got) - 1)))
        fit = f" (they fit base {base:.4g})"
    raise WeightsError(
        f"{source}: rope_embed.periods {got[:4].tolist()}... differ from base {rope.base:g} "
        f"** (2k / {rope.head_dim // 2}) = {expected[:4].tolist()}... by more than bfloat16 "
        f"rounding{fit}: the file was trained with other RoPE settings than the official "
        "DINOv3 models; pass an official DINOv3 file"
    )


def dinov3_state(
    state: dict[str, torch.Tensor], model: nn.Module, spec: BackboneSpec, source: str
) -> dict[str, torch.Tensor]:
    """A DINOv3 file's tensors under official keys, checked to belong to ``spec``.

    Raises:
        WeightsError: the file name or its ``local_cls_norm`` keys show it is another backbone's
            (e.g. satellite weights under a web name), its RoPE periods differ, or a Hugging
            Face layer lacks part of its attention projection.
    """
    check_file_name(Path(source), spec)
    if is_hf_dinov3(state):
        state = dinov3_hf_to_official(state)
        _fill_from_model(state, model)
    else:
        state = dict(state)
        check_local_cls_norm(state, spec, source)
    check_periods(state, model, source)
    return state

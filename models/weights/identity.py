"""Which backbone a weights file is for: its family (keys, ``config.json``), its architecture
(``config.json``), and among backbones of one shape what its tensors show, what its names say,
and the user's choice, in that order.

Backbones of one shape can hold different weights: DINOv3's ViT-L and 7B exist pre-trained on
web images (LVD-1689M) and on satellite images (SAT-493M), which expect other input statistics.
Evidence, strongest first:

1. the tensors: the shapes (width, blocks, feed-forward, registers), and for the official
   ViT-L files ``local_cls_norm.*``, which only the SAT-493M file holds (Hugging Face and timm
   files drop it);
2. the names: an official file name's hash (``-eadcf0ff``), also behind a symbolic link; a
   known hub id (``timm/vit_large_patch16_dinov3.sat493m``, also as a hub-cache folder
   ``models--timm--…``); one of our backbone names (``dinov3_vitl16_sat.safetensors``); timm's
   ``config.json``; a data set's name (``sat493m``, ``lvd1689m``) in the file's, its folder's
   or the hub id's name. A name that the tensors contradict is ignored;
3. otherwise the backbone the user chose, with a `WeightsWarning` where a backbone of the same
   shape exists (the file cannot say which it is).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from claravid.models.backbones.specs import (
    BACKBONES,
    FAMILIES,
    BackboneSpec,
    spec_for_hash,
    spec_for_hub_id,
)
from claravid.models.weights.dinov2 import DINOV2
from claravid.models.weights.dinov3 import DINOV3
from claravid.models.weights.formats import WeightsError, WeightsFamily

#: Each family's declared formats, by family name.
WEIGHTS_FAMILIES: dict[str, WeightsFamily] = {"dinov2": DINOV2, "dinov3": DINOV3}

_DATASETS = {"sat493m": "SAT-493M", "lvd1689m": "LVD-1689M", "lvd142m": "LVD-142M"}


class WeightsWarning(UserWarning):
    """Weights loaded as the backbone chosen, although the file cannot show that it is."""


@dataclass(frozen=True)
class Shape:
    """What a state dict under official names shows of its architecture.

    Attributes:
        embed_dim: Token width.
        depth: Number of blocks.
        ffn: ``"mlp"`` or ``"swiglu"``.
        patch_size: Patch side.
        tokens: Register/storage tokens.
        local_cls_norm: Whether it holds ``local_cls_norm.*`` (None: the format drops it).
    """

    embed_dim: int
    depth: int
    ffn: str
    patch_size: int
    tokens: int
    local_cls_norm: bool | None

    def fits(self, arch: Mapping[str, Any]) -> bool:
        """Whether a backbone built with ``arch`` has this shape."""
        tokens = arch.get("num_storage_tokens", arch.get("num_register_tokens", 0))
        same = (
            self.embed_dim == arch["embed_dim"]
            and self.depth == arch["depth"]
            and self.ffn == arch["ffn"]
            and self.patch_size == arch["patch_size"]
            and self.tokens == tokens
        )
        if self.local_cls_norm is not None and "local_cls_norm" in arch:
            same = same and self.local_cls_norm == bool(arch["local_cls_norm"])
        return same

    def __str__(self) -> str:
        ffn = "SwiGLU" if self.ffn == "swiglu" else "MLP"
        tokens = f", {self.tokens} registers" if self.tokens else ""
        return f"{self.embed_dim} wide, {self.depth} blocks, {ffn}, patch {self.patch_size}{tokens}"


def state_shape(state: Mapping[str, torch.Tensor], keeps_local_cls_norm: bool) -> Shape | None:
    """The `Shape` of official-named tensors, or None when they are not a ViT's."""
    patch = state.get("patch_embed.proj.weight")
    blocks = {int(m.group(1)) for k in state if (m := re.match(r"blocks\.(\d+)\.", k))}
    if patch is None or patch.ndim != 4 or not blocks:
        return None
    swiglu = any(re.fullmatch(r"blocks\.0\.mlp\.(w1|w12)\.weight", k) for k in state)
    extra = state.get("storage_tokens", state.get("register_tokens"))
    return Shape(
        embed_dim=int(patch.shape[0]),
        depth=max(blocks) + 1,
        ffn="swiglu" if swiglu else "mlp",
        patch_size=int(patch.shape[-1]),
        tokens=int(extra.shape[1]) if extra is not None and extra.ndim == 3 else 0,
        local_cls_norm=any(k.startswith("local_cls_norm.") for k in state)
        if keeps_local_cls_norm
        else None,
    )


def _with(spec: BackboneSpec, overrides: Mapping[str, Any]) -> dict[str, Any]:
    return {**spec.arch, **{k: v for k, v in overrides.items() if k in spec.arch}}


def fitting(shape: Shape, family: str, overrides: Mapping[str, Any]) -> list[BackboneSpec]:
    """The named backbones of ``family`` with this shape (size overrides applied alike)."""
    return [s for s in BACKBONES.values() if s.family == family and shape.fits(_with(s, overrides))]


def named_owner(
    names: list[str], config: Mapping[str, Any] | None
) -> tuple[BackboneSpec, str] | None:
    """(backbone, why) that an official hash, a known hub id or timm's config names, if any."""
    for name in names:
        m = re.search(r"-([0-9a-f]{8})\.[A-Za-z]+$", name)
        owner = spec_for_hash(m.group(1)) if m else None
        if owner is not None:
            return owner, f"its name {name} is the official file of {owner.name}"
        owner = spec_for_hub_id(name)
        if owner is not None:
            return owner, f"the hub repository {name} holds {owner.name}"
    for name in names:  # one of our names: dinov3_vitl16_sat.safetensors
        words = re.findall(r"dinov[23]_[a-z0-9_]+?(?=[^a-z0-9_]|$)", name.lower())
        owner = next((BACKBONES[w] for w in words if w in BACKBONES), None)
        if owner is not None:
            return owner, f"its name {name} is {owner.name}'s"
    if config and isinstance(config.get("architecture"), str):
        tag = (config.get("pretrained_cfg") or {}).get("tag")
        owner = spec_for_hub_id(f"timm/{config['architecture']}.{tag}")
        if owner is not None:
            why = f"timm's config.json names {config['architecture']}.{tag}, that is {owner.name}"
            return owner, why
    return None


def named_dataset(names: list[str]) -> tuple[str, str] | None:
    """(pre-training data set, the name that says it) from ``sat493m``-like words, if any."""
    for name in names:
        for word, dataset in _DATASETS.items():
            if word in name.lower():
                return dataset, name
    return None


def siblings(spec: BackboneSpec) -> list[BackboneSpec]:
    """Other named backbones of the same shape (pre-trained on other data)."""
    keys = ("embed_dim", "depth", "num_heads", "ffn", "patch_size")
    return [
        s
        for s in BACKBONES.values()
        if s is not spec
        and s.family == spec.family
        and all(s.arch[k] == spec.arch[k] for k in keys)
    ]


def check_identity(
    shape: Shape | None,
    spec: BackboneSpec,
    overrides: Mapping[str, Any],
    names: list[str],
    config: Mapping[str, Any] | None,
    source: str,
) -> None:
    """Refuse weights that show or say they are another backbone's; warn where nothing can tell.

    Raises:
        WeightsError: naming the backbone the weights are for, and what shows it.
    """
    if shape is None:
        return  # not a ViT state: the strict load lists the keys
    fit = fitting(shape, spec.family, overrides)
    if not fit:
        return  # no named backbone has this shape: the strict load lists the differences
    owner = named_owner(names, config)
    told = owner if owner is not None and owner[0] in fit else None
    if spec not in fit:
        # Named backbones of the chosen one's size first (only size overrides make several fit).
        size = ("embed_dim", "depth", "num_heads")
        near = [s for s in fit if all(s.arch[k] == spec.arch[k] for k in size)]
        right = told[0] if told else _by_dataset(fit, names) or (near or fit)[0]
        others = [s.name for s in (near or fit) if s is not right]
        also = f" (or {', '.join(others)}: the tensors do not tell)" if others and not told else ""
        said = ""
        if owner is not None and owner[0] not in fit:
            said = f"; {owner[1]}, which its tensors contradict"
        norm = _cls_norm_words(shape) if "local_cls_norm" in spec.arch else ""
        raise WeightsError(
            f"{source} holds the weights of {right.name}{also} ({shape}{norm}), not of "
            f"{spec.name}{said}: build {right.name} for it (inputs normalised with mean "
            f"{right.mean}, std {right.std})"
        )
    if told is not None:
        right = told[0]
        if right is not spec:
            raise WeightsError(
                f"{source}: {told[1]} ({right.weights.dataset}), not {spec.name} "
                f"({spec.weights.dataset}): build {right.name} for it (inputs normalised with "
                f"mean {right.mean}, std {right.std})"
            )
        return
    alike = [s for s in siblings(spec) if s in fit]
    if not alike:
        return
    by_data = named_dataset(names)
    if by_data is not None:
        named = next((s for s in [spec, *alike] if s.weights.dataset == by_data[0]), None)
        if named is spec:
            return
        if named is not None:
            raise WeightsError(
                f"{source}: the name {by_data[1]} says {by_data[0]}, so these are the weights of "
                f"{named.name}, not of {spec.name} ({spec.weights.dataset}): build {named.name} "
                f"for it (inputs normalised with mean {named.mean}, std {named.std})"
            )
    alike_listed = ", ".join(f"{s.name} ({s.weights.dataset})" for s in alike)
    dropped = (
        "Hugging Face and timm files drop local_cls_norm; " if shape.local_cls_norm is None else ""
    )
    warnings.warn(
        f"{source} does not show whether it holds the weights of {spec.name} "
        f"({spec.weights.dataset}) or of {alike_listed}: same shapes ({dropped}no official hash, "
        f"known hub id or data-set name such as sat493m in its name). Loaded as {spec.name}, as "
        "chosen; if it is the other, build that backbone, whose input statistics differ",
        WeightsWarning,
        stacklevel=3,
    )


def _by_dataset(fit: list[BackboneSpec], names: list[str]) -> BackboneSpec | None:
    said = named_dataset(names)
    return next((s for s in fit if said and s.weights.dataset == said[0]), None)


def _cls_norm_words(shape: Shape) -> str:
    if shape.local_cls_norm is None:
        return ""
    return ", with local_cls_norm.*" if shape.local_cls_norm else ", without local_cls_norm.*"


def check_family(
    state: Mapping[str, Any],
    spec: BackboneSpec,
    source: Any,
    config: Mapping[str, Any] | None = None,
) -> None:
    """Raise `WeightsError` naming both families when the weights are the other family's (by
    keys only one family's files have, else by what their config.json says)."""
    found: dict[str, str] = {}
    for family, weights in WEIGHTS_FAMILIES.items():
        pattern = re.compile(weights.marker)
        key = next((k for k in sorted(state) if pattern.fullmatch(k)), None)
        if key is not None:
            found[family] = f"it has {key!r}"
    if len(found) != 1 and config:
        said = str(config.get("model_type") or config.get("architecture") or "")
        found = {f: f"its config.json says {said!r}" for f in WEIGHTS_FAMILIES if f in said}
    if len(found) != 1:
        return
    family, evidence = next(iter(found.items()))
    if family == spec.family:
        return
    raise WeightsError(
        f"{source} holds {FAMILIES[family]} weights ({evidence}), but {spec.name} is a "
        f"{spec.family_name} backbone: build a {FAMILIES[family]} backbone ({family}_...) for "
        f"this file, or pass {spec.family_name} weights for {spec.name}"
    )


def check_config(
    config: Mapping[str, Any] | None,
    source: str,
    family: WeightsFamily,
    arch: Mapping[str, Any],
    spec: BackboneSpec,
) -> None:
    """Refuse weights whose transformers ``config.json`` describes another architecture."""
    if not config or "model_type" not in config:
        return
    if family.model_types and config["model_type"] not in family.model_types:
        raise WeightsError(
            f"{source}: its config.json says model_type {config['model_type']!r}, not a "
            f"{spec.family_name} ViT ({', '.join(family.model_types)}): these are another "
            f"model's weights; pass {spec.family_name} weights for {spec.name}"
        )
    wrong = []
    for key, expected in family.hf_config.items():
        if key not in config:
            continue
        value, want = config[key], expected(arch)
        if isinstance(value, str) and not isinstance(want, str):
            wrong.append(f"{key} is the string {value!r}, where transformers reads a "
                         f"{type(want).__name__} ({want!r} for the model)")  # fmt: skip
        elif not _same(value, want):
            wrong.append(f"{key} {value!r} (the model: {want!r})")
    if wrong:
        raise WeightsError(
            f"{source}: its config.json describes another model than {spec.name}: "
            f"{', '.join(wrong)}; these weights were trained with other settings, so their "
            "features would be wrong: pass the weights of the backbone you build"
        )


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str):
        return a == b
    if isinstance(a, (list, tuple)):
        return len(set(a)) == 1 and _same(a[0], b)  # e.g. image_size [518, 518]
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-9)
    except (TypeError, ValueError):
        return a == b

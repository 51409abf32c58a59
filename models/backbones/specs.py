"""What each named backbone is: one frozen description per name, in one plain dict.

A `BackboneSpec` holds everything that differs between backbones: the family (``"dinov2"`` or
``"dinov3"``, which picks the module class), the constructor arguments, the DPT defaults (tapped
blocks and widths), the input statistics the weights were trained with, and where the official
weights come from. Code elsewhere reads these fields (or the built module's ``patch_size``,
``mean``, ``std`` ...) instead of parsing names or testing the family.

This module imports nothing heavy (no torch), so the ONNX Runtime side can read it too. Building
a module from a description is `claravid.models.backbones.build`. See docs/models.md for the tables.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

#: ImageNet's per-channel mean and std (RGB, of pixels in [0, 1]): the DINOv2 models and the
#: DINOv3 models pre-trained on web images (LVD-1689M) expect inputs normalised with them.
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: The statistics of SAT-493M, the satellite images of the DINOv3 ``_sat`` models.
SAT493M_MEAN = (0.430, 0.411, 0.296)
SAT493M_STD = (0.213, 0.156, 0.143)
#: Input statistics by name, for a model file that records none (``--statistics``, an ONNX file
#: exported elsewhere): ``(mean, std)``.
NAMED_STATISTICS = {
    "imagenet": (IMAGENET_MEAN, IMAGENET_STD),
    "sat493m": (SAT493M_MEAN, SAT493M_STD),
}

#: How messages name each family.
FAMILIES = {"dinov2": "DINOv2", "dinov3": "DINOv3"}
#: Where the licence-gated DINOv3 files are requested (the download URL comes by e-mail).
DINOV3_REQUEST_URL = "https://ai.meta.com/resources/models-and-libraries/dinov3-downloads/"
DINOV2_BASE_URL = "https://dl.fbaipublicfiles.com/dinov2"
#: The built default of `claravid.models.build_model`.
DEFAULT_BACKBONE = "dinov2_vitl14"


@dataclass(frozen=True)
class WeightsInfo:
    """Where a backbone's official pre-trained weights come from.

    Attributes:
        dataset: The pre-training images: ``LVD-142M`` (DINOv2), ``LVD-1689M`` (DINOv3 web) or
            ``SAT-493M`` (DINOv3 satellite).
        file: The official file name.
        url: Its download URL, or None when the files are licence-gated (DINOv3).
        licence: The weights' licence.
        hub: Repositories of the Hugging Face hub holding the same weights in other formats
            (``facebook/...`` for transformers, ``timm/...``), usable as ``weights=``.
    """

    dataset: str
    file: str
    url: str | None
    licence: str
    hub: tuple[str, ...] = ()

    @property
    def hash(self) -> str | None:
        """The 8 hex digits the official DINOv3 file names end with, or None."""
        match = re.search(r"-([0-9a-f]{8})\.pth$", self.file)
        return match.group(1) if match else None


@dataclass(frozen=True)
class DPTDefaults:
    """The DPT head's defaults for a backbone size.

    Attributes:
        layers: Tapped block indices, fine to coarse.
        features: Fusion width.
        out_channels: Reassemble widths of the four levels, fine to coarse.
    """

    layers: tuple[int, int, int, int]
    features: int
    out_channels: tuple[int, int, int, int]


@dataclass(frozen=True)
class BackboneSpec:
    """One named backbone.

    Attributes:
        name: The name, e.g. ``"dinov3_vitl16_sat"``.
        family: ``"dinov2"`` or ``"dinov3"``: which module class takes ``arch``.
        arch: Constructor arguments of that class (read-only).
        dpt: Default DPT head for this size.
        mean: Per-channel input mean (RGB, pixels in [0, 1]) the weights were trained with.
        std: Per-channel input std.
        weights: Provenance of the official weights.
    """

    name: str
    family: str
    arch: Mapping[str, Any]
    dpt: DPTDefaults
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    weights: WeightsInfo

    @property
    def patch_size(self) -> int:
        """Patch side in pixels: H and W must be multiples of it."""
        return int(self.arch["patch_size"])

    @property
    def embed_dim(self) -> int:
        """Token width D."""
        return int(self.arch["embed_dim"])

    @property
    def depth(self) -> int:
        """Number of blocks."""
        return int(self.arch["depth"])

    @property
    def family_name(self) -> str:
        """``DINOv2`` or ``DINOv3``, as messages write it."""
        return FAMILIES[self.family]


# Size names of the hub repositories: ours -> (transformers, timm).
_HUB_SIZES = {
    "vits": ("small", "small"),
    "vitb": ("base", "base"),
    "vitl": ("large", "large"),
    "vitg": ("giant", "giant"),
    "vits16": ("vits16", "small"),
    "vits16plus": ("vits16plus", "small_plus"),
    "vitb16": ("vitb16", "base"),
    "vitl16": ("vitl16", "large"),
    "vith16plus": ("vith16plus", "huge_plus"),
    "vit7b16": ("vit7b16", "7b"),
}


def _dinov2(
    arch: str, dims: tuple[int, int, int], ffn: str, registers: bool, dpt: DPTDefaults
) -> BackboneSpec:
    """A DINOv2 description: ViT-``arch``/14 trained at 518 (a 37x37 positional grid)."""
    embed_dim, depth, num_heads = dims
    base = f"dinov2_{arch}14"
    file = f"{base}_reg4_pretrain.pth" if registers else f"{base}_pretrain.pth"
    hf, timm = _HUB_SIZES[arch]
    hub = (
        f"facebook/dinov2-{'with-registers-' if registers else ''}{hf}",
        f"timm/vit_{timm}_patch14_{'reg4_' if registers else ''}dinov2.lvd142m",
    )
    return BackboneSpec(
        name=f"{base}_reg" if registers else base,
        family="dinov2",
        arch=MappingProxyType(
            {
                "embed_dim": embed_dim,
                "depth": depth,
                "num_heads": num_heads,
                "ffn": ffn,
                "mlp_ratio": 4.0,
                "patch_size": 14,
                "img_size": 518,
                # The register models resize the positional table to the exact grid with
                # antialiasing; the others scale by (grid + 0.1) / 37 (vit.py).
                "num_register_tokens": 4 if registers else 0,
                "interpolate_offset": 0.0 if registers else 0.1,
                "interpolate_antialias": registers,
            }
        ),
        dpt=dpt,
        mean=IMAGENET_MEAN,
        std=IMAGENET_STD,
        weights=WeightsInfo(
            "LVD-142M", file, f"{DINOV2_BASE_URL}/{base}/{file}", "Apache-2.0", hub
        ),
    )


def _dinov3(
    name: str,
    dims: tuple[int, int, int],
    ffn: tuple[str, float, int],
    dpt: DPTDefaults,
    file: str,
    *,
    sat: bool = False,
    qkv_bias: bool = True,
    local_cls_norm: bool = False,
    rope_dtype: str = "bf16",
) -> BackboneSpec:
    """A DINOv3 description: ViT/16 with 4 storage tokens, RoPE, LayerNorm eps 1e-5."""
    embed_dim, depth, num_heads = dims
    kind, ratio, align = ffn
    size = name.removeprefix("dinov3_").removesuffix("_sat")
    hf, timm = _HUB_SIZES[size]
    tag = "sat493m" if sat else "lvd1689m"
    # timm has a _qkvb variant (with the q/v biases) of every distilled model.
    variants = ("",) if size == "vit7b16" else ("", "_qkvb")
    hub = (
        f"facebook/dinov3-{hf}-pretrain-{tag}",
        *(f"timm/vit_{timm}_patch16_dinov3{v}.{tag}" for v in variants),
    )
    return BackboneSpec(
        name=name,
        family="dinov3",
        arch=MappingProxyType(
            {
                "embed_dim": embed_dim,
                "depth": depth,
                "num_heads": num_heads,
                "ffn": kind,
                "ffn_ratio": ratio,
                "swiglu_align": align,
                "qkv_bias": qkv_bias,
                "patch_size": 16,
                "num_storage_tokens": 4,
                "rope_base": 100.0,
                # The distilled models were trained with bfloat16 RoPE, and their released
                # files hold the periods rounded to bfloat16; the 7B models used float32.
                "rope_dtype": rope_dtype,
                "norm_eps": 1e-5,
                # The SAT-493M ViT-L and both 7B files also hold this pre-training-only norm;
                # the module keeps it (unused) so those files load strictly.
                "local_cls_norm": local_cls_norm,
            }
        ),
        dpt=dpt,
        mean=SAT493M_MEAN if sat else IMAGENET_MEAN,
        std=SAT493M_STD if sat else IMAGENET_STD,
        weights=WeightsInfo("SAT-493M" if sat else "LVD-1689M", file, None, "DINOv3 License", hub),
    )


# DPT defaults per size. S, B, L (both families) and DINOv2's g are the DINOv2 set-up the project
# started from; DINOv3's H+ and 7B have no DINOv2 counterpart (docs/models.md explains them).
_DPT_S = DPTDefaults((2, 5, 8, 11), 64, (48, 96, 192, 384))
_DPT_B = DPTDefaults((2, 5, 8, 11), 128, (96, 192, 384, 768))
_DPT_L = DPTDefaults((4, 11, 17, 23), 256, (256, 512, 1024, 1024))
_DPT_G = DPTDefaults((9, 19, 29, 39), 384, (1536, 1536, 1536, 1536))
_DPT_HPLUS = DPTDefaults((7, 15, 23, 31), 320, (320, 640, 1280, 1280))
_DPT_7B = DPTDefaults((9, 19, 29, 39), 512, (2048, 2048, 2048, 2048))

_MLP4 = ("mlp", 4.0, 8)
_SWIGLU6 = ("swiglu", 6.0, 8)
_SWIGLU3_64 = ("swiglu", 3.0, 64)

_SPECS = [
    _dinov2("vits", (384, 12, 6), "mlp", False, _DPT_S),
    _dinov2("vits", (384, 12, 6), "mlp", True, _DPT_S),
    _dinov2("vitb", (768, 12, 12), "mlp", False, _DPT_B),
    _dinov2("vitb", (768, 12, 12), "mlp", True, _DPT_B),
    _dinov2("vitl", (1024, 24, 16), "mlp", False, _DPT_L),
    _dinov2("vitl", (1024, 24, 16), "mlp", True, _DPT_L),
    _dinov2("vitg", (1536, 40, 24), "swiglu", False, _DPT_G),
    _dinov2("vitg", (1536, 40, 24), "swiglu", True, _DPT_G),
    _dinov3(
        "dinov3_vits16",
        (384, 12, 6),
        _MLP4,
        _DPT_S,
        "dinov3_vits16_pretrain_lvd1689m-08c60483.pth",
    ),
    _dinov3(
        "dinov3_vits16plus",
        (384, 12, 6),
        _SWIGLU6,
        _DPT_S,
        "dinov3_vits16plus_pretrain_lvd1689m-4057cbaa.pth",
    ),
    _dinov3(
        "dinov3_vitb16",
        (768, 12, 12),
        _MLP4,
        _DPT_B,
        "dinov3_vitb16_pretrain_lvd1689m-73cec8be.pth",
    ),
    _dinov3(
        "dinov3_vitl16",
        (1024, 24, 16),
        _MLP4,
        _DPT_L,
        "dinov3_vitl16_pretrain_lvd1689m-8aa4cbdd.pth",
    ),
    _dinov3(
        "dinov3_vitl16_sat",
        (1024, 24, 16),
        _MLP4,
        _DPT_L,
        "dinov3_vitl16_pretrain_sat493m-eadcf0ff.pth",
        sat=True,
        local_cls_norm=True,
    ),
    _dinov3(
        "dinov3_vith16plus",
        (1280, 32, 20),
        _SWIGLU6,
        _DPT_HPLUS,
        "dinov3_vith16plus_pretrain_lvd1689m-7c1da9a5.pth",
    ),
    _dinov3(
        "dinov3_vit7b16",
        (4096, 40, 32),
        _SWIGLU3_64,
        _DPT_7B,
        "dinov3_vit7b16_pretrain_lvd1689m-a955f4ea.pth",
        qkv_bias=False,
        local_cls_norm=True,
        rope_dtype="fp32",
    ),
    _dinov3(
        "dinov3_vit7b16_sat",
        (4096, 40, 32),
        _SWIGLU3_64,
        _DPT_7B,
        "dinov3_vit7b16_pretrain_sat493m-a6675841.pth",
        sat=True,
        qkv_bias=False,
        local_cls_norm=True,
        rope_dtype="fp32",
    ),
]

#: Every named backbone, by name.
BACKBONES: dict[str, BackboneSpec] = {spec.name: spec for spec in _SPECS}
BACKBONE_NAMES: tuple[str, ...] = tuple(BACKBONES)


def backbone_spec(name: str) -> BackboneSpec:
    """The description of ``name``.

    Raises:
        ValueError: an unknown name (e.g. from a checkpoint of a newer version), naming the
            known ones.
    """
    spec = BACKBONES.get(name) if isinstance(name, str) else None
    if spec is None:
        raise ValueError(f"unknown backbone {name!r}: choose one of {', '.join(BACKBONE_NAMES)}")
    return spec


def backbone_config(name: str, **overrides: Any) -> dict[str, Any]:
    """Constructor arguments of a named backbone, with optional overrides (tiny test models).

    Args:
        name: One of ``BACKBONE_NAMES``, e.g. ``"dinov2_vitl14"`` or ``"dinov3_vitl16"``.
        **overrides: Any argument of the description's ``arch``.

    Raises:
        ValueError: an unknown name or argument.
    """
    cfg = dict(backbone_spec(name).arch)
    unknown = set(overrides) - set(cfg)
    if unknown:
        raise ValueError(f"unknown backbone arguments {sorted(unknown)}; known: {sorted(cfg)}")
    cfg.update(overrides)
    return cfg


def spec_for_hash(file_hash: str) -> BackboneSpec | None:
    """The backbone whose official file name ends with ``-<file_hash>.pth``, if any."""
    return next((s for s in _SPECS if s.weights.hash == file_hash), None)


def spec_for_hub_id(repo_id: str) -> BackboneSpec | None:
    """The backbone whose weights the hub repository ``repo_id`` holds, if it is a known one."""
    lowered = repo_id.lower()
    return next((s for s in _SPECS if lowered in (h.lower() for h in s.weights.hub)), None)

"""The backbone descriptions: every name, the official architectures and the DPT defaults, and
that the built modules expose one interface whatever the family."""

import pytest
import torch

from claravid.models import BACKBONES, backbone_spec, build_backbone, build_model
from claravid.models.backbones.specs import BACKBONE_NAMES

# The published DINOv3 architectures (facebookresearch/dinov3, hub/backbones.py) and the DPT
# taps of the issue: name -> (dim, depth, heads, ffn, SwiGLU hidden or MLP hidden, qkv bias,
# taps, millions of parameters as the DINOv3 model card rounds them: 21M, 29M, 86M, 300M, 840M,
# 6,716M).
DINOV3 = {
    "dinov3_vits16": (384, 12, 6, "fc1", 1536, True, (2, 5, 8, 11), 21),
    "dinov3_vits16plus": (384, 12, 6, "w1", 1536, True, (2, 5, 8, 11), 29),
    "dinov3_vitb16": (768, 12, 12, "fc1", 3072, True, (2, 5, 8, 11), 86),
    "dinov3_vitl16": (1024, 24, 16, "fc1", 4096, True, (4, 11, 17, 23), 300),
    "dinov3_vitl16_sat": (1024, 24, 16, "fc1", 4096, True, (4, 11, 17, 23), 300),
    "dinov3_vith16plus": (1280, 32, 20, "w1", 5120, True, (7, 15, 23, 31), 840),
    "dinov3_vit7b16": (4096, 40, 32, "w1", 8192, False, (9, 19, 29, 39), 6716),
    "dinov3_vit7b16_sat": (4096, 40, 32, "w1", 8192, False, (9, 19, 29, 39), 6716),
}
SAT = {"mean": (0.430, 0.411, 0.296), "std": (0.213, 0.156, 0.143)}
WEB = {"mean": (0.485, 0.456, 0.406), "std": (0.229, 0.224, 0.225)}


def test_every_name():
    dinov2 = [f"dinov2_vit{s}14{r}" for s in "sblg" for r in ("", "_reg")]
    assert sorted(BACKBONE_NAMES) == sorted([*dinov2, *DINOV3])
    assert set(BACKBONES) == set(BACKBONE_NAMES)


@pytest.mark.parametrize("name", sorted(DINOV3))
def test_official_dinov3_architectures(name):
    dim, depth, heads, ffn, hidden, qkv_bias, taps, millions = DINOV3[name]
    with torch.device("meta"):
        model = build_backbone(name)
    state = model.state_dict()
    assert (model.embed_dim, model.n_blocks, model.num_heads, model.patch_size) == (
        dim,
        depth,
        heads,
        16,
    )
    assert state["cls_token"].shape == (1, 1, dim)
    assert state["storage_tokens"].shape == (1, 4, dim)
    assert state["mask_token"].shape == (1, dim)
    assert state["rope_embed.periods"].shape == (dim // heads // 4,)
    assert state[f"blocks.{depth - 1}.mlp.{ffn}.weight"].shape == (hidden, dim)
    assert ("blocks.0.attn.qkv.bias" in state) == qkv_bias
    assert ("blocks.0.attn.qkv.bias_mask" in state) == qkv_bias
    assert "pos_embed" not in state
    assert ("local_cls_norm.weight" in state) == (name in ("dinov3_vitl16_sat",) or "7b" in name)
    count = sum(v.numel() for k, v in state.items() if not k.startswith("local_cls_norm")) / 1e6
    count -= sum(v.numel() for k, v in state.items() if k.endswith(("bias_mask", "periods"))) / 1e6
    assert count == pytest.approx(millions, rel=0.03)
    assert backbone_spec(name).dpt.layers == taps
    assert model.norm.eps == 1e-5


@pytest.mark.parametrize("name", BACKBONE_NAMES)
def test_one_interface_for_both_families(name):
    with torch.device("meta"):
        model = build_backbone(name)
    spec = backbone_spec(name)
    stats = SAT if name.endswith("_sat") else WEB
    assert model.mean == stats["mean"] and model.std == stats["std"]
    assert all(isinstance(v, float) for v in (*model.mean, *model.std))
    assert model.patch_size == (14 if name.startswith("dinov2_") else 16) == spec.patch_size
    assert (model.embed_dim, model.n_blocks) == (spec.embed_dim, spec.depth)
    for method in (
        "get_intermediate_layers",
        "check_input",
        "check_input_size",
        "freeze_pos_embed",
    ):
        assert callable(getattr(model, method))


def test_dpt_defaults_of_the_segmenter():
    expected = {  # taps, features, reassemble widths (docs/models.md)
        "dinov2_vits14": ((2, 5, 8, 11), 64, [48, 96, 192, 384]),
        "dinov2_vitl14_reg": ((4, 11, 17, 23), 256, [256, 512, 1024, 1024]),
        "dinov2_vitg14": ((9, 19, 29, 39), 384, [1536] * 4),
        "dinov3_vits16plus": ((2, 5, 8, 11), 64, [48, 96, 192, 384]),
        "dinov3_vitb16": ((2, 5, 8, 11), 128, [96, 192, 384, 768]),
        "dinov3_vitl16_sat": ((4, 11, 17, 23), 256, [256, 512, 1024, 1024]),
        "dinov3_vith16plus": ((7, 15, 23, 31), 320, [320, 640, 1280, 1280]),
        "dinov3_vit7b16": ((9, 19, 29, 39), 512, [2048] * 4),
    }
    for name, (layers, features, widths) in expected.items():
        with torch.device("meta"):
            model = build_model(name, num_classes=4)
        assert model.layers == layers, name
        assert model.head.layer_rn[0].out_channels == features, name
        assert [r.project.out_channels for r in model.head.reassemble] == widths, name
        assert model.model_args["backbone"] == name


def test_unknown_backbone_names_the_known_ones():
    for bad in ("dinov4_vitl16", "vit_l", None):
        with pytest.raises(
            ValueError, match=r"unknown backbone .*: choose one of .*dinov3_vit7b16"
        ):
            build_model(bad, num_classes=2)
    with pytest.raises(ValueError, match=r"unknown backbone arguments \['rope_theta'\]"):
        build_backbone("dinov3_vits16", rope_theta=10.0)


def test_weights_provenance():
    assert backbone_spec("dinov3_vitl16_sat").weights.dataset == "SAT-493M"
    assert backbone_spec("dinov3_vitl16_sat").weights.hash == "eadcf0ff"
    assert backbone_spec("dinov3_vit7b16").weights.file == (
        "dinov3_vit7b16_pretrain_lvd1689m-a955f4ea.pth"
    )
    assert all(BACKBONES[n].weights.url is None for n in DINOV3)  # licence-gated
    assert backbone_spec("dinov2_vitl14_reg").weights.url == (
        "https://dl.fbaipublicfiles.com/dinov2/dinov2_vitl14/dinov2_vitl14_reg4_pretrain.pth"
    )

"""timm's files (the ungated DINOv3 re-hosts and timm's DINOv2): made from official states by
timm's own key mapping, written out in the test material; they load strictly and give the same
features as the official file of the same weights."""

import pytest
import torch

from claravid.models import WeightsError, build_backbone
from tests.helpers.weights import saved
from tests.models.backbones.reference import random_official_state, to_timm_dinov2
from tests.models.weights.official_v3 import released_v3_state, to_timm
from tests.tiny import TINY_V3

TINY_V2 = {"embed_dim": 32, "depth": 2, "num_heads": 2, "img_size": 28}
X3 = torch.randn(1, 3, 48, 80, generator=torch.Generator().manual_seed(0))
X2 = torch.randn(1, 3, 42, 70, generator=torch.Generator().manual_seed(0))


def _features(model, x):
    with torch.no_grad():
        return model.get_intermediate_layers(x, 2, return_class_token=True)


def _assert_same(a, b):
    for (pa, ca), (pb, cb) in zip(a, b, strict=True):
        assert torch.equal(pa, pb) and torch.equal(ca, cb)


# (timm repository, backbone, its released qkv bias kept as q_bias/v_bias)
DINOV3 = [
    ("timm/vit_large_patch16_dinov3.lvd1689m", "dinov3_vitl16", False),
    ("timm/vit_large_patch16_dinov3_qkvb.sat493m", "dinov3_vitl16_sat", True),
    ("timm/vit_small_plus_patch16_dinov3_qkvb.lvd1689m", "dinov3_vits16plus", True),
    ("timm/vit_huge_plus_patch16_dinov3.lvd1689m", "dinov3_vith16plus", False),
    ("timm/vit_7b_patch16_dinov3.sat493m", "dinov3_vit7b16_sat", False),
]


@pytest.mark.parametrize(("repo", "name", "qkvb"), DINOV3)
def test_dinov3_timm_file_gives_the_official_features(tmp_path, repo, name, qkvb):
    state = released_v3_state(build_backbone(name, **TINY_V3), name, seed=7)
    official = build_backbone(name, weights=saved(state, tmp_path / f"{name}.pth"), **TINY_V3)
    # A downloaded timm repository: the folder name says which weights these are.
    folder = tmp_path / repo.split("/")[1]
    path = saved(to_timm(state, qkvb=qkvb), folder / "model.safetensors")
    assert "rope_embed.periods" not in to_timm(state) and "mask_token" not in to_timm(state)
    timm = build_backbone(name, weights=path, **TINY_V3)
    _assert_same(_features(timm, X3), _features(official, X3))
    assert torch.equal(timm.rope_embed.periods, state["rope_embed.periods"].float())


def test_dinov3_qkvb_keeps_the_biases_and_the_plain_variant_has_none(tmp_path):
    """ViT-S has non-zero q/v biases: the _qkvb file keeps them (same features); the plain
    variant drops them, as timm does, and loads with a zero bias."""
    state = released_v3_state(build_backbone("dinov3_vits16", **TINY_V3), "dinov3_vits16", 1)
    official = build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "o.pth"), **TINY_V3)
    qkvb = build_backbone(
        "dinov3_vits16", weights=saved(to_timm(state), tmp_path / "q.safetensors"), **TINY_V3
    )
    _assert_same(_features(qkvb, X3), _features(official, X3))
    plain = to_timm(state, qkvb=False)
    assert not any("bias" in k and ".attn." in k and "proj" not in k for k in plain)
    model = build_backbone(
        "dinov3_vits16", weights=saved(plain, tmp_path / "p.safetensors"), **TINY_V3
    )
    assert not model.blocks[0].attn.qkv.bias.any()


def test_a_timm_sat_file_needs_a_name_that_says_so(tmp_path):
    """timm drops local_cls_norm, so the web/SAT check reads the names."""
    name = "dinov3_vitl16_sat"
    state = released_v3_state(build_backbone(name, **TINY_V3), name, seed=2)
    sat = saved(
        to_timm(state), tmp_path / "vit_large_patch16_dinov3_qkvb.sat493m" / "m.safetensors"
    )
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vitl16", weights=sat, **TINY_V3)
    message = str(err.value)
    assert "\n" not in message
    assert "vit_large_patch16_dinov3_qkvb.sat493m says SAT-493M" in message
    assert "build dinov3_vitl16_sat for it" in message
    build_backbone(name, weights=sat, **TINY_V3)
    # No name that tells: the choice stands, and a warning says what cannot be told apart.
    plain = saved(to_timm(state), tmp_path / "downloads" / "model.safetensors")
    with pytest.warns(UserWarning, match=r"does not show whether .* dinov3_vitl16 \(LVD-1689M\)"):
        build_backbone("dinov3_vitl16", weights=plain, **TINY_V3)


def test_a_timm_file_of_another_size_or_family_says_which_it_is(tmp_path):
    # Real widths, one block each: S+ (384 wide, SwiGLU) given to S (384 wide, MLP).
    one = {"depth": 1}
    state = released_v3_state(build_backbone("dinov3_vits16plus", **one), "dinov3_vits16plus")
    path = saved(to_timm(state), tmp_path / "w" / "model.safetensors")
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vits16", weights=path, **one)
    message = str(err.value)
    assert "holds the weights of dinov3_vits16plus (384 wide, 1 blocks, SwiGLU" in message
    assert "not of dinov3_vits16: build dinov3_vits16plus for it" in message
    v2 = to_timm_dinov2(random_official_state(build_backbone("dinov2_vits14_reg", **TINY_V2)))
    with pytest.raises(WeightsError, match=r"holds DINOv2 weights .* is a DINOv3 backbone"):
        build_backbone("dinov3_vits16", weights=saved(v2, tmp_path / "v2.safetensors"), **TINY_V3)


@pytest.mark.parametrize("name", ["dinov2_vits14", "dinov2_vits14_reg", "dinov2_vitg14_reg"])
def test_dinov2_timm_file_gives_the_official_features(tmp_path, name):
    """Without registers timm keeps the official names (no mask token); with registers the CLS
    position is folded into the token and the table holds patch positions only; giant: fc1/fc2."""
    state = random_official_state(build_backbone(name, **TINY_V2), seed=4)
    official = build_backbone(name, weights=saved(state, tmp_path / "o.pth"), **TINY_V2)
    timm_state = to_timm_dinov2(state)
    registers = name.endswith("_reg")
    assert timm_state["pos_embed"].shape[1] == (4 if registers else 5)  # 2x2 grid (+ CLS)
    timm = build_backbone(name, weights=saved(timm_state, tmp_path / "t.safetensors"), **TINY_V2)
    # At the trained grid and at another size (the positional table is resized).
    for x in (torch.randn(1, 3, 28, 28), X2):
        got, want = _features(timm, x), _features(official, x)
        for (pa, ca), (pb, cb) in zip(got, want, strict=True):
            torch.testing.assert_close(pa, pb, atol=1e-6, rtol=0)
            torch.testing.assert_close(ca, cb, atol=1e-6, rtol=0)

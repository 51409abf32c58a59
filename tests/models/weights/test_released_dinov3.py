"""DINOv3 files as Meta released them: RoPE periods rounded to bfloat16 (the distilled models were
trained with bfloat16 RoPE; 7B with float32) and, for B, L and H+, an all-zero qkv bias.

The official code loads such a file into its float32 ``periods`` buffer and computes the angles
from the loaded values. The oracle here is transformers' independent ``DINOv3ViTModel`` told the
same (its ``inv_freq`` set to 1 / the file's periods); its own float32 periods give other
features, and the tests check that they do, so that a model recomputing the periods fails.
"""

import pytest
import torch

from claravid.models import WeightsError, build_backbone
from tests.helpers.weights import released_state, saved
from tests.models.weights.official_v3 import official_periods, to_hugging_face
from tests.tiny import TINY_V3

transformers = pytest.importorskip("transformers")

# name -> what transformers' config needs to describe the same model.
HF_ARGS = {
    "dinov3_vitl16": {"use_gated_mlp": False, "hidden_act": "gelu"},
    "dinov3_vits16plus": {"use_gated_mlp": True, "hidden_act": "silu"},
}
# 640x480 (a 30x40 grid, the shape of a 4:3 photo), and odd grids: 13x9 and 3x5.
SIZES = [(480, 640), (208, 144), (48, 80)]


def _transformers(name, state):
    hidden = next(v for k, v in state.items() if k.endswith(("mlp.fc1.weight", "mlp.w1.weight")))
    config = transformers.DINOv3ViTConfig(
        hidden_size=TINY_V3["embed_dim"],
        num_hidden_layers=TINY_V3["depth"],
        num_attention_heads=TINY_V3["num_heads"],
        intermediate_size=hidden.shape[0],
        num_register_tokens=4,
        patch_size=16,
        attn_implementation="eager",
        **HF_ARGS[name],
    )
    model = transformers.DINOv3ViTModel(config).eval()
    model.load_state_dict(to_hugging_face(state, "model."), strict=True)
    return model


def test_released_periods_of_a_head_of_64():
    """Head width 64 (every released model but 7B's 128): the values the released files hold."""
    model = build_backbone("dinov3_vits16", embed_dim=128, num_heads=2, depth=1)
    assert model.rope_embed.periods[:4].tolist() == [1.0, 1.3359375, 1.78125, 2.375]
    assert model.rope_embed.periods.dtype == torch.float32
    big = build_backbone("dinov3_vit7b16", embed_dim=128, num_heads=2, depth=1)  # float32 RoPE
    want = torch.tensor([100.0 ** (k / 16) for k in range(16)], dtype=torch.float64)
    torch.testing.assert_close(big.rope_embed.periods.double(), want, atol=0, rtol=2e-7)


@pytest.mark.parametrize("name", sorted(HF_ARGS))
def test_a_released_file_gives_the_official_features(tmp_path, name):
    state = released_state(name, seed=5)
    assert state["rope_embed.periods"].dtype == torch.bfloat16  # as the official model saves it
    model = build_backbone(name, weights=saved(state, tmp_path / "w.pth"), **TINY_V3)
    theirs = _transformers(name, state)
    own_rope = theirs.rope_embeddings.inv_freq.clone()
    loaded_rope = 1 / state["rope_embed.periods"].float()
    for h, w in SIZES:
        x = torch.randn(2, 3, h, w, generator=torch.Generator().manual_seed(h))
        with torch.no_grad():
            got = model.get_intermediate_layers(x, [0, 2], return_class_token=True)
            theirs.rope_embeddings.inv_freq.copy_(loaded_rope)
            hidden = theirs(x, output_hidden_states=True).hidden_states
            theirs.rope_embeddings.inv_freq.copy_(own_rope)
            float32_rope = theirs(x).last_hidden_state
        for block, (patches, cls) in zip((0, 2), got, strict=True):
            want = theirs.norm(hidden[block + 1])
            assert patches.shape == (2, (h // 16) * (w // 16), TINY_V3["embed_dim"])
            torch.testing.assert_close(patches, want[:, 5:], atol=1e-5, rtol=0)
            torch.testing.assert_close(cls, want[:, 0], atol=1e-5, rtol=0)
        # Periods recomputed in float32 (transformers' own) are far off: the check bites.
        assert (got[1][0] - float32_rope[:, 5:]).abs().max() > 1e-3


@pytest.mark.parametrize("name", ["dinov3_vitl16", "dinov3_vit7b16"])
def test_a_file_without_periods_gets_the_released_ones(tmp_path, name):
    """The official file and the Hugging Face file of one checkpoint give the same features:
    bfloat16 periods for the distilled ViT-L, float32 ones for 7B."""
    state = released_state(name, seed=5)
    # Files named after the backbone: nothing else tells 7B's web file from its SAT one.
    official = build_backbone(name, weights=saved(state, tmp_path / f"{name}.pth"), **TINY_V3)
    hf_path = saved(to_hugging_face(state, "model."), tmp_path / name / "model.safetensors")
    hf = build_backbone(name, weights=hf_path, **TINY_V3)
    assert torch.equal(hf.rope_embed.periods, state["rope_embed.periods"].float())
    x = torch.randn(1, 3, 208, 144, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        want = official.get_intermediate_layers(x, 3, return_class_token=True)
        got = hf.get_intermediate_layers(x, 3, return_class_token=True)
    for (a, ca), (b, cb) in zip(got, want, strict=True):
        assert torch.equal(a, b) and torch.equal(ca, cb)


def test_released_qkv_bias_is_zero_for_b_l_and_h_plus():
    for name in ("dinov3_vitb16", "dinov3_vitl16", "dinov3_vith16plus"):
        assert not released_state(name, seed=5)["blocks.0.attn.qkv.bias"].any(), name
    assert released_state("dinov3_vits16", seed=5)["blocks.0.attn.qkv.bias"].any()


def test_periods_of_another_base_are_refused(tmp_path):
    state = released_state("dinov3_vits16", seed=5)
    state["rope_embed.periods"] = official_periods(4, torch.float32, base=10000.0)
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "w.pth"), **TINY_V3)
    message = str(err.value)
    assert "\n" not in message
    assert "rope_embed.periods [1.0, 10.0, 100.0, 1000.0]... differ from base 100" in message
    assert "(they fit base 1e+04)" in message and "other RoPE settings" in message
    # Base 102: the periods move by up to 1.5 %, more than a bfloat16 rounding (0.8 %).
    state["rope_embed.periods"] = official_periods(4, torch.float32, base=102.0)
    with pytest.raises(WeightsError, match="fit base 102"):
        build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "b.pth"), **TINY_V3)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_a_state_dict_saved_in_half_precision_loads(tmp_path, dtype):
    """``model.half().state_dict()`` rounds the periods too: that is not another RoPE."""
    state = {k: v.to(dtype) for k, v in released_state("dinov3_vit7b16", seed=5).items()}
    path = saved(state, tmp_path / "dinov3_vit7b16.pth")
    model = build_backbone("dinov3_vit7b16", weights=path, **TINY_V3)
    assert torch.equal(model.rope_embed.periods, state["rope_embed.periods"].float())
    assert model.rope_embed.periods.dtype == torch.float32


def test_a_cast_model_keeps_float32_periods():
    """7B's float32 periods survive ``.to(torch.bfloat16)`` and ``.half()`` (the angles must
    not lose digits), and follow the model to its device."""
    model = build_backbone("dinov3_vit7b16", **TINY_V3)
    want = model.rope_embed.periods.clone()
    for cast in (lambda m: m.to(torch.bfloat16), lambda m: m.half(), lambda m: m.float()):
        cast(model)
        assert model.rope_embed.periods.dtype == torch.float32
        assert torch.equal(model.rope_embed.periods, want)
    assert model.blocks[0].attn.qkv.weight.dtype == torch.float32
    model.to("meta")
    assert model.rope_embed.periods.device.type == "meta"

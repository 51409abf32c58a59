"""The DINOv3 backbone against transformers' independent ``DINOv3ViTModel``, and its interface.

Both are fed the same random weights (official layout for ours, renamed by hand for theirs) with
LayerScale gammas near 1, on a non-square input (a 3x5 patch grid).
"""

import pytest
import torch

from claravid.models import build_backbone, build_model
from tests.models.weights.official_v3 import random_official_v3_state, to_hugging_face
from tests.tiny import TINY_V3

transformers = pytest.importorskip("transformers")

X = torch.randn(2, 3, 48, 80, generator=torch.Generator().manual_seed(1))
# name, overrides, what transformers' config needs to describe the same model.
CASES = {
    "mlp": ("dinov3_vitl16", {}, {"use_gated_mlp": False, "hidden_act": "gelu"}),
    "swiglu": ("dinov3_vith16plus", {}, {"use_gated_mlp": True, "hidden_act": "silu"}),
    "7b_like": (  # SwiGLU rounded to 64, no qkv bias at all
        "dinov3_vit7b16",
        {},
        {"use_gated_mlp": True, "hidden_act": "silu", "query_bias": False, "value_bias": False},
    ),
}


def _pair(case: str, prefix: str = "model."):
    """(ours, theirs, official state) with the same random weights."""
    name, overrides, hf_args = CASES[case]
    ours = build_backbone(name, **TINY_V3, **overrides).eval()
    state = random_official_v3_state(ours, seed=2)
    ours.load_state_dict(state, strict=True)
    mlp = ours.blocks[0].mlp
    hidden = (mlp.w1 if hasattr(mlp, "w1") else mlp.fc1).out_features
    config = transformers.DINOv3ViTConfig(
        hidden_size=TINY_V3["embed_dim"],
        num_hidden_layers=TINY_V3["depth"],
        num_attention_heads=TINY_V3["num_heads"],
        intermediate_size=hidden,
        num_register_tokens=4,
        patch_size=16,
        attn_implementation="eager",  # explicit softmax: independent of our SDPA call
        **hf_args,
    )
    theirs = transformers.DINOv3ViTModel(config).eval()
    hf_state = to_hugging_face(state, prefix)
    theirs.load_state_dict(hf_state, strict=True)
    return ours, theirs, state


@pytest.fixture(scope="module", params=sorted(CASES))
def pair(request):
    return _pair(request.param)


def test_hidden_widths_follow_the_official_rounding():
    # SwiGLU: int(ratio * D * 2/3) rounded up to 8 (S+, H+) or 64 (7B).
    with torch.device("meta"):
        splus = build_backbone("dinov3_vits16plus", embed_dim=40, depth=1, num_heads=2)
        big = build_backbone("dinov3_vit7b16", embed_dim=40, depth=1, num_heads=2)
    assert splus.blocks[0].mlp.w1.out_features == 160  # int(240 * 2/3) = 160
    assert big.blocks[0].mlp.w1.out_features == 128  # int(120 * 2/3) = 80 -> 128
    assert big.blocks[0].attn.qkv.bias is None
    assert "blocks.0.attn.qkv.bias_mask" not in big.state_dict()


def test_last_layer_matches_transformers(pair):
    ours, theirs, _ = pair
    with torch.no_grad():
        want = theirs(X).last_hidden_state
        ((patches, cls),) = ours.get_intermediate_layers(X, 1, return_class_token=True)
        pooled = ours(X)
    assert patches.shape == (2, 15, TINY_V3["embed_dim"])
    diff = max((patches - want[:, 5:]).abs().max(), (cls - want[:, 0]).abs().max())
    assert diff <= 1e-4, diff
    torch.testing.assert_close(pooled, want[:, 0], atol=1e-4, rtol=0)


def test_intermediate_layers_match_transformers(pair):
    ours, theirs, _ = pair
    with torch.no_grad():
        hidden = theirs(X, output_hidden_states=True).hidden_states  # embeddings, then layers
        normed = ours.get_intermediate_layers(X, [0, 1], return_class_token=True)
        raw = ours.get_intermediate_layers(X, 2, norm=False)
        grids = ours.get_intermediate_layers(X, [1], reshape=True)
    for i, (patches, cls) in enumerate(normed):
        want = theirs.norm(hidden[i + 1])
        torch.testing.assert_close(patches, want[:, 5:], atol=1e-4, rtol=0)
        torch.testing.assert_close(cls, want[:, 0], atol=1e-4, rtol=0)
    for block, patches in zip((1, 2), raw, strict=True):  # n=2: the last two blocks
        torch.testing.assert_close(patches, hidden[block + 1][:, 5:], atol=1e-4, rtol=0)
    # reshape: [B, D, rows, cols] with token r * 5 + c at [..., r, c]
    assert grids[0].shape == (2, TINY_V3["embed_dim"], 3, 5)
    torch.testing.assert_close(grids[0][:, :, 2, 1], normed[1][0][:, 2 * 5 + 1])


def test_small_tokens_match_transformers():
    """Tokens of variance ~1e-7 entering the first LayerNorm: there eps (1e-5) dominates the
    variance, so a wrong eps (DINOv2's 1e-6) is a large error, not a 1e-6 one."""
    ours, theirs, state = _pair("mlp")
    small = dict(state)
    for key in ("cls_token", "storage_tokens", "patch_embed.proj.weight", "patch_embed.proj.bias"):
        small[key] = state[key] * 1e-4
    ours.load_state_dict(small)
    theirs.load_state_dict(to_hugging_face(small, "model."))
    with torch.no_grad():
        want = theirs(X).last_hidden_state[:, 5:]
        got = ours.get_intermediate_layers(X, 1)[0]
    torch.testing.assert_close(got, want, atol=1e-4, rtol=0)


def test_hugging_face_file_loads_in_both_spellings(tmp_path):
    """A Hugging Face file gets the periods of the released official file (bfloat16 for H+), so
    its features are transformers' with those periods, not with its own float32 ones."""
    from safetensors.torch import save_file

    _, theirs, state = _pair("swiglu")
    released = torch.tensor([1.0, 3.15625, 10.0, 31.625])  # 100 ** (k / 4) in bfloat16
    theirs.rope_embeddings.inv_freq.copy_(1 / released)
    with torch.no_grad():
        want = theirs(X).last_hidden_state[:, 5:]
    for prefix in ("", "model."):  # transformers 4.57 wrote layer.N, 5.x model.layer.N
        path = tmp_path / prefix / "model.safetensors"
        path.parent.mkdir(exist_ok=True)
        save_file(to_hugging_face(state, prefix), str(path))
        loaded = build_backbone("dinov3_vith16plus", weights=path, **TINY_V3)
        for key, value in loaded.state_dict().items():
            want_value = state[key]
            if key.endswith("qkv.bias"):  # transformers stores no key bias: it loads as zero
                d = TINY_V3["embed_dim"]
                want_value = torch.cat([want_value[:d], torch.zeros(d), want_value[2 * d :]])
            if key == "rope_embed.periods":
                want_value = released
            assert torch.equal(value, want_value), key
        with torch.no_grad():
            got = loaded.get_intermediate_layers(X, 1)[0]
        torch.testing.assert_close(got, want, atol=1e-5, rtol=0)


def test_tokens_and_interface():
    model = build_backbone("dinov3_vits16", **TINY_V3).eval()
    assert (model.patch_size, model.embed_dim, model.n_blocks) == (16, 64, 3)
    assert model.state_dict()["storage_tokens"].shape == (1, 4, 64)
    assert model.state_dict()["mask_token"].shape == (1, 64)
    assert (
        model.state_dict()["blocks.0.attn.qkv.bias_mask"].tolist()
        == [1.0] * 64 + [0.0] * 64 + [1.0] * 64
    )
    assert model.norm.eps == 1e-5
    with pytest.raises(ValueError, match=r"block indices \[3\] must be in \[0, 2\]"):
        model.get_intermediate_layers(X, [3])


def test_the_key_bias_is_masked():
    """Changing the key bias changes nothing; the query bias does."""
    model = build_backbone("dinov3_vits16", **TINY_V3).eval()
    model.load_state_dict(random_official_v3_state(model, seed=4))
    with torch.no_grad():
        before = model.get_intermediate_layers(X, 1)[0]
        bias = model.blocks[0].attn.qkv.bias
        bias[64:128] += 3.0
        assert torch.equal(model.get_intermediate_layers(X, 1)[0], before)
        bias[:64] += 3.0
        assert not torch.allclose(model.get_intermediate_layers(X, 1)[0], before, atol=1e-3)


@pytest.mark.parametrize(
    ("size", "message"),
    [
        ((630, 630), r"630x630 is not a multiple of the patch size 16: pad .* 640x640 .*624x624"),
        ((48, 70), r"48x70 is not a multiple of the patch size 16: pad .* 48x80 .*48x64"),
    ],
)
def test_sizes_off_the_grid_name_the_nearest_valid_ones(size, message):
    model = build_backbone("dinov3_vits16", **TINY_V3)
    with pytest.raises(ValueError, match=message):
        model(torch.zeros(1, 3, *size))
    with pytest.raises(ValueError, match=message):
        model.check_input_size(*size)
    with pytest.raises(ValueError, match=message):
        model.freeze_pos_embed(*size)


def test_float_input_message_states_the_backbone_statistics():
    model = build_backbone("dinov3_vitl16_sat", **TINY_V3)
    with pytest.raises(
        TypeError, match=r"mean \(0.43, 0.411, 0.296\), std \(0.213, 0.156, 0.143\)"
    ):
        model(torch.zeros(1, 3, 32, 32, dtype=torch.uint8))


def test_frozen_rope_gives_the_same_features():
    model = build_backbone("dinov3_vits16", **TINY_V3).eval()
    with torch.no_grad():
        want = model.get_intermediate_layers(X, 2)
        model.freeze_pos_embed(48, 80)
        assert model.rope_embed._frozen is not None
        torch.testing.assert_close(model.get_intermediate_layers(X, 2), want, atol=0, rtol=0)
        other = torch.randn(1, 3, 64, 32)
        frozen_other = model.get_intermediate_layers(other, 1)
        model.freeze_pos_embed(None)
        torch.testing.assert_close(model.get_intermediate_layers(other, 1), frozen_other)
    assert model.rope_embed._frozen is None


def _tiny_segmenter():
    torch.manual_seed(0)
    return build_model(
        "dinov3_vits16",
        num_classes=3,
        layers=[0, 1, 2, 3],
        features=16,
        out_channels=[8, 16, 32, 32],
        backbone_kwargs={**TINY_V3, "depth": 4},
    ).eval()


def test_autocast_keeps_the_rope_in_float32():
    model = _tiny_segmenter()
    seen = []
    model.backbone.rope_embed.register_forward_hook(lambda m, a, out: seen.append(out))
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        low = model(X)
    assert low.dtype == torch.bfloat16
    assert seen and all(t.dtype == torch.float32 for out in seen for t in out)
    with torch.no_grad():
        ref = model(X)
    assert (low.float() - ref).abs().max() < 0.1 * ref.std()


@pytest.mark.slow
def test_torch_compile_matches_eager():
    model = _tiny_segmenter()
    # aot_eager: the graph capture (dynamo + AOT autograd) without inductor's C++ build, which
    # takes minutes on a 2-core CPU.
    compiled = torch.compile(model, backend="aot_eager")
    with torch.no_grad():
        torch.testing.assert_close(compiled(X), model(X), atol=1e-5, rtol=1e-5)
        other = torch.randn(1, 3, 32, 64)
        torch.testing.assert_close(compiled(other), model(other), atol=1e-5, rtol=1e-5)


@pytest.mark.slow
def test_torch_export_with_dynamic_size_matches_eager():
    model = _tiny_segmenter()
    grid = torch.export.Dim("grid_h", min=1, max=64), torch.export.Dim("grid_w", min=1, max=64)
    shapes = {"x": {0: torch.export.Dim("batch", min=1, max=8), 2: 16 * grid[0], 3: 16 * grid[1]}}
    with torch.no_grad():
        exported = torch.export.export(model, (X,), dynamic_shapes=shapes)
        # Other sizes and batches than the example (grids of at least 3x3: the DPT head's
        # half-resolution level is specialised to more than one row and column).
        for x in (X, torch.randn(3, 3, 64, 96), torch.randn(1, 3, 80, 48)):
            torch.testing.assert_close(exported.module()(x), model(x), atol=1e-5, rtol=1e-5)

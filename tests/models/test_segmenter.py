"""The segmenter: frozen backbone, trainable DPT head, sizes, precision and compile."""

import numpy as np
import pytest
import torch

from claravid.models import DPTHead, build_model
from tests.models.backbones.reference import random_official_state, reference_layers
from tests.tiny import VIT
from tests.tiny import VIT_56 as TINY
from tests.tiny import WIDE_HEAD as HEAD


def _model(name="dinov2_vits14", **kw):
    torch.manual_seed(0)
    return build_model(name, num_classes=5, backbone_kwargs=TINY, **{**HEAD, **kw})


def test_forward_backward_trains_only_the_head():
    model = _model().train()
    assert not model.backbone.training and model.head.training
    x = torch.randn(2, 3, 42, 70)
    logits = model(x)
    assert logits.shape == (2, 5, 42, 70)
    logits.square().mean().backward()
    assert all(p.grad is None for p in model.backbone.parameters())
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.head.parameters())
    head_count = sum(p.numel() for p in model.head.parameters())
    assert model.num_trainable_parameters() == head_count
    assert f"trainable={head_count:,}" in repr(model)


def test_backbone_keeps_no_activations():
    """Autograd saves exactly what the head alone saves: nothing of the backbone."""
    model = _model().train()
    x = torch.randn(1, 3, 42, 42)
    saved = []

    def count(t):
        saved.append(t.numel())
        return t

    with torch.autograd.graph.saved_tensors_hooks(count, lambda t: t):
        model(x)
    total = sum(saved)
    with torch.no_grad():
        feats = model.backbone.get_intermediate_layers(x, model.layers, return_class_token=True)
    saved.clear()
    with torch.autograd.graph.saved_tensors_hooks(count, lambda t: t):
        model.head(feats, 3, 3, (42, 42))
    assert total == sum(saved) > 0


def test_an_unfrozen_backbone_trains_end_to_end_with_the_gradients_of_the_composition():
    """``unfreeze_backbone``: the backbone's gradients are those of backbone-then-head composed
    by hand (a copy of the same weights); the outputs do not change; ``freeze_backbone`` undoes
    it; the backbone stays in eval mode in training."""
    import copy

    torch.manual_seed(0)
    tiny = {"embed_dim": 32, "depth": 4, "num_heads": 2}  # SAT ViT-L: with local_cls_norm
    model = build_model("dinov3_vitl16_sat", 5, backbone_kwargs=tiny, **HEAD).train()
    reference = copy.deepcopy(model)
    x = torch.randn(1, 3, 32, 48)  # 2 x 3 patches of 16, non-square
    frozen = model(x).detach()
    assert model.unfreeze_backbone() is model and not model.backbone_frozen
    model.train()
    assert not model.backbone.training and model.head.training
    logits = model(x)
    torch.testing.assert_close(logits, frozen, atol=0, rtol=0)
    logits.square().mean().backward()
    reference.backbone.requires_grad_(True)
    feats = reference.backbone.get_intermediate_layers(x, [0, 1, 2, 3], return_class_token=True)
    reference.head(feats, 2, 3, (32, 48)).square().mean().backward()
    ours = dict(model.backbone.named_parameters())
    compared = 0
    for name, p in reference.backbone.named_parameters():
        if name.startswith(("mask_token", "local_cls_norm")):  # pre-training only: frozen
            assert p.grad is None  # no loss reaches them
            assert not ours[name].requires_grad and ours[name].grad is None, name
        else:
            torch.testing.assert_close(ours[name].grad, p.grad, atol=1e-6, rtol=1e-5)
            compared += 1
    assert compared == 62 and ours["blocks.0.attn.qkv.weight"].grad.abs().sum() > 0
    total = sum(p.numel() for p in model.parameters())
    pretraining = model.backbone.mask_token.numel() + 2 * 32  # the norm's weight and bias
    assert model.num_trainable_parameters() == total - pretraining
    model.freeze_backbone()
    assert model.backbone_frozen and model.num_trainable_parameters() == sum(
        p.numel() for p in model.head.parameters()
    )


def test_head_gets_the_official_backbone_features():
    model = _model("dinov2_vits14_reg").eval()
    state = random_official_state(model.backbone, seed=5)
    model.backbone.load_state_dict(state)
    x = torch.randn(1, 3, 56, 42)
    captured = {}

    def keep(module, args):
        captured["feats"] = args[0]

    model.head.register_forward_pre_hook(keep)
    model(x)
    ref = reference_layers(state, x, 2, [0, 1, 2, 3], registers=True)
    for (tokens, cls), (ref_tokens, ref_cls) in zip(captured["feats"], ref, strict=True):
        torch.testing.assert_close(tokens, ref_tokens, atol=1e-4, rtol=0)
        torch.testing.assert_close(cls, ref_cls, atol=1e-4, rtol=0)


def test_pyramid_sizes_at_630():
    model = _model().eval()
    sizes = []
    for rn in model.head.layer_rn:
        rn.register_forward_hook(lambda m, a, out: sizes.append(tuple(out.shape[-2:])))
    with torch.no_grad():
        out = model(torch.randn(1, 3, 630, 630))
    assert sizes == [(180, 180), (90, 90), (45, 45), (23, 23)]
    assert out.shape == (1, 5, 630, 630)


def test_cls_readout_and_defaults():
    model = _model(use_cls=True)
    assert model.head.reassemble[0].readout is not None
    assert model(torch.randn(1, 3, 28, 42)).shape == (1, 5, 28, 42)
    with torch.device("meta"):
        big = build_model("dinov2_vitl14", num_classes=19)
    assert big.layers == (4, 11, 17, 23)
    assert [r.project.out_channels for r in big.head.reassemble] == [256, 512, 1024, 1024]
    assert big.head.layer_rn[0].out_channels == 256


def test_odd_size_and_bad_arguments():
    model = _model()
    with pytest.raises(ValueError, match=r"pad or resize it to 42x56"):
        model(torch.randn(1, 3, 40, 50))
    with pytest.raises(ValueError, match=r"layers \[7\] outside the backbone's 4 blocks"):
        _model(layers=[0, 1, 2, 7])
    with pytest.raises(ValueError, match=r"out_channels needs 4 entries"):
        DPTHead(32, 3, 16, [8, 16, 32])


def test_channels_last_and_autocast():
    model = _model().eval()
    x = torch.randn(2, 3, 42, 56)
    with torch.no_grad():
        ref = model(x)
        last = model.to(memory_format=torch.channels_last)(x.to(memory_format=torch.channels_last))
        torch.testing.assert_close(last, ref, atol=1e-5, rtol=1e-5)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model(x)
    assert low.dtype == torch.bfloat16
    # bf16 keeps ~3 significant digits: compare relative to the logits' spread.
    assert (low.float() - ref).abs().max() < 0.1 * ref.std()


@pytest.mark.slow
def test_torch_compile_matches_eager():
    model = _model().train()
    # aot_eager traces forward and backward like inductor but skips C++ codegen, which takes
    # minutes on a 2-core CPU; the GPU benchmark covers the inductor backend.
    compiled = torch.compile(model, backend="aot_eager")
    x = torch.randn(2, 3, 42, 56)
    out = compiled(x)
    out.mean().backward()
    torch.testing.assert_close(out, model(x), atol=1e-4, rtol=1e-4)
    assert all(p.grad is None for p in model.backbone.parameters())
    assert model.head.layer_rn[0].weight.grad is not None


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: np.zeros((1, 3, 28, 28), np.float32), TypeError, r"got numpy.ndarray.*from_numpy"),
        (lambda: [[0.0]], TypeError, r"expected a torch.Tensor of float images \[B,3,H,W\]"),
        (lambda: torch.zeros(3, 28, 28), ValueError, r"got shape \[3, 28, 28\].*x\[None\]"),
        (lambda: torch.zeros(1, 1, 3, 28, 28), ValueError, r"got shape \[1, 1, 3, 28, 28\]"),
        (lambda: torch.zeros(1, 3, 28, 28, dtype=torch.int32), TypeError, r"dtype torch.int32"),
        (lambda: torch.zeros(3, 28, 28, dtype=torch.uint8), ValueError, r"shape \[3, 28, 28\]"),
        (lambda: torch.zeros(1, 28, 28, 3), ValueError, r"28 channels.*permute to \[B,3,H,W\]"),
        (lambda: torch.zeros(1, 4, 28, 28), ValueError, r"got 4 channels"),
        (lambda: torch.zeros(1, 1, 28, 28), ValueError, r"got 1 channels"),
        (lambda: torch.zeros(1, 3, 30, 28), ValueError, r"pad or resize it to 42x28"),
        (lambda: torch.zeros(1, 3, 0, 28), ValueError, r"0x28 is empty"),
    ],
)
def test_wrong_input_says_what_is_expected(make, error, match):
    model = _model().eval()
    with pytest.raises(error, match=match) as info:
        model(make())
    assert "normalised" in str(info.value) or "patch size 14" in str(info.value)
    with pytest.raises(error, match=match):  # the backbone alone checks the same way
        model.backbone.get_intermediate_layers(make(), 1)


def test_input_checks_are_skipped_while_tracing(monkeypatch):
    model = _model().eval()
    odd = torch.randn(1, 3, 40, 50)  # not a patch multiple: refused in eager mode
    with pytest.raises(ValueError, match="patch size"):
        model(odd)
    monkeypatch.setattr(torch.jit, "is_tracing", lambda: True)
    with torch.no_grad():  # while tracing the check would specialise shapes: it is skipped
        assert model(odd).shape == (1, 5, 40, 50)


@pytest.mark.parametrize(("h", "w"), [(28, 70), (56, 42)])
def test_forward_is_backbone_then_head_on_non_square_input(h, w):
    """The token grid is (rows, columns) = (H/14, W/14): composed here by hand from the
    backbone's tapped layers and the head, on inputs wider and taller than square."""
    model = _model().eval()
    x = torch.randn(1, 3, h, w)
    with torch.no_grad():
        feats = model.backbone.get_intermediate_layers(x, [0, 1, 2, 3], return_class_token=True)
        assert feats[0][0].shape[1] == (h // 14) * (w // 14)
        expected = model.head(feats, h // 14, w // 14, (h, w))
        got = model(x)
    assert got.shape == (1, 5, h, w)
    torch.testing.assert_close(got, expected, atol=1e-6, rtol=0)


def test_a_compiled_model_checks_its_input():
    # Before: the check was skipped while compiling, so a compiled model took 100x100.
    model = torch.compile(_model().eval(), backend="eager")
    with torch.no_grad():
        assert model(torch.randn(1, 3, 28, 42)).shape == (1, 5, 28, 42)
        with pytest.raises(ValueError, match=r"100x100 is not a multiple of the patch size 14"):
            model(torch.randn(1, 3, 100, 100))
        with pytest.raises(TypeError, match=r"got dtype torch.int64"):
            model(torch.zeros(1, 3, 28, 28, dtype=torch.int64))
        pixels = torch.randint(0, 256, (1, 3, 28, 42), dtype=torch.uint8)
        torch.testing.assert_close(model(pixels), model._orig_mod(pixels), atol=1e-5, rtol=0)


def test_uint8_input_is_normalised_with_the_backbones_own_statistics():
    """A satellite backbone's uint8 input equals the float path normalised by hand with the
    SAT-493M statistics (ImageNet's would give other logits)."""
    torch.manual_seed(0)
    model = build_model("dinov3_vitl16_sat", num_classes=5, backbone_kwargs=VIT, **HEAD).eval()
    assert model.mean == (0.430, 0.411, 0.296) and model.std == (0.213, 0.156, 0.143)
    pixels = torch.randint(0, 256, (2, 3, 32, 48), dtype=torch.uint8)
    sat_mean = torch.tensor([0.430, 0.411, 0.296]).view(1, 3, 1, 1)
    sat_std = torch.tensor([0.213, 0.156, 0.143]).view(1, 3, 1, 1)
    imagenet_mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    imagenet_std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        got = model(pixels)
        by_hand = model((pixels.float() / 255 - sat_mean) / sat_std)
        imagenet = model((pixels.float() / 255 - imagenet_mean) / imagenet_std)
    torch.testing.assert_close(got, by_hand, atol=1e-5, rtol=0)
    assert (got - imagenet).abs().max() > 1e-3


def test_uint8_input_of_a_dinov2_model_uses_imagenet_statistics():
    model = _model().eval()
    assert model.mean == (0.485, 0.456, 0.406) and model.std == (0.229, 0.224, 0.225)
    pixels = torch.randint(0, 256, (1, 3, 28, 42), dtype=torch.uint8)
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    with torch.no_grad():
        torch.testing.assert_close(
            model(pixels), model((pixels / 255 - mean) / std), atol=1e-5, rtol=0
        )
    with pytest.raises(TypeError, match=r"dtype torch.uint8"):  # the backbone takes floats only
        model.backbone.get_intermediate_layers(pixels, 1)

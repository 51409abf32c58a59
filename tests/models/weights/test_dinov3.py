"""DINOv3 weight files: official .pth and Hugging Face safetensors, and every way they can be the
wrong file (keys, family, web vs satellite, licence, truncation, memory)."""

import pytest
import torch

from claravid.models import WeightsError, build_backbone, build_model, official_url
from claravid.models.backbones.memory import NotEnoughMemoryError
from tests.helpers.weights import dinov2_to_hugging_face, saved
from tests.models.backbones.reference import random_official_state
from tests.models.weights.official_v3 import random_official_v3_state, to_hugging_face
from tests.tiny import TINY_V3
from tests.tiny import VIT_2 as TINY_V2

X = torch.randn(1, 3, 32, 48, generator=torch.Generator().manual_seed(0))


def _state(name="dinov3_vits16", seed=3, **extra):
    return random_official_v3_state(build_backbone(name, **{**TINY_V3, **extra}), seed=seed)


def test_official_pth_round_trip(tmp_path):
    state = _state("dinov3_vits16plus")
    path = saved(state, tmp_path / "w.pth")
    model = build_backbone("dinov3_vits16plus", weights=path, **TINY_V3)
    assert not model.training
    assert set(model.state_dict()) == set(state)
    for key, value in model.state_dict().items():
        assert torch.equal(value, state[key]), key


def test_sat_and_7b_files_with_local_cls_norm_load(tmp_path):
    for name in ("dinov3_vitl16_sat", "dinov3_vit7b16"):
        state = _state(name)
        assert "local_cls_norm.weight" in state
        model = build_backbone(name, weights=saved(state, tmp_path / f"{name}.pth"), **TINY_V3)
        assert torch.equal(model.local_cls_norm.bias, state["local_cls_norm.bias"])
        # Accepted and ignored: it changes no output.
        with torch.no_grad():
            before = model(X)
            model.local_cls_norm.weight.fill_(7.0)
            assert torch.equal(model(X), before)


def test_missing_and_unexpected_keys_are_listed(tmp_path):
    state = _state()
    del state["blocks.1.ls2.gamma"]
    state["blocks.0.attn.qkv.extra"] = torch.zeros(3)
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "w.pth"), **TINY_V3)
    message = str(err.value)
    assert "missing keys (1): blocks.1.ls2.gamma" in message
    assert "unexpected keys (1): blocks.0.attn.qkv.extra" in message


def test_hugging_face_missing_and_unexpected_keys(tmp_path):
    hf = to_hugging_face(_state(), "model.")
    del hf["model.layer.2.norm1.bias"]
    hf["model.layer.0.attention.rotary.weight"] = torch.zeros(2)
    with pytest.raises(WeightsError) as err:
        build_backbone(
            "dinov3_vits16", weights=saved(hf, tmp_path / "model.safetensors"), **TINY_V3
        )
    message = str(err.value)
    assert "missing keys (1): blocks.2.norm1.bias" in message
    assert "unexpected keys (1): layer.0.attention.rotary.weight" in message
    hf = to_hugging_face(_state(), "model.")
    del hf["model.layer.1.attention.v_proj.weight"]
    with pytest.raises(WeightsError, match=r"lacks layer.1.attention.v_proj.weight: the file is"):
        build_backbone(
            "dinov3_vits16", weights=saved(hf, tmp_path / "b" / "m.safetensors"), **TINY_V3
        )


@pytest.mark.parametrize("hugging_face", [False, True])
def test_a_dinov2_file_into_a_dinov3_backbone(tmp_path, hugging_face):
    state = random_official_state(build_backbone("dinov2_vits14_reg", **TINY_V2))
    if hugging_face:
        state = dinov2_to_hugging_face(state)
    path = saved(state, tmp_path / ("model.safetensors" if hugging_face else "v2.pth"))
    with pytest.raises(WeightsError, match=r"holds DINOv2 weights .* is a DINOv3 backbone"):
        build_backbone("dinov3_vits16", weights=path, **TINY_V3)


@pytest.mark.parametrize("hugging_face", [False, True])
def test_a_dinov3_file_into_a_dinov2_backbone(tmp_path, hugging_face):
    state = _state()
    if hugging_face:
        state = to_hugging_face(state, "model.")
    path = saved(state, tmp_path / ("model.safetensors" if hugging_face else "v3.pth"))
    with pytest.raises(WeightsError, match=r"holds DINOv3 weights .* is a DINOv2 backbone"):
        build_backbone("dinov2_vits14_reg", weights=path, **TINY_V2)


def test_truncated_file(tmp_path):
    path = saved(_state(), tmp_path / "w.pth")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(WeightsError, match=r"w.pth: the torch.save archive is truncated"):
        build_backbone("dinov3_vits16", weights=path, **TINY_V3)
    hf = saved(to_hugging_face(_state()), tmp_path / "model.safetensors")
    hf.write_bytes(hf.read_bytes()[:-100])
    with pytest.raises(WeightsError, match=r"model.safetensors as safetensors .*truncated"):
        build_backbone("dinov3_vits16", weights=hf, **TINY_V3)


def test_sat_file_under_the_web_name_by_local_cls_norm(tmp_path):
    sat = saved(_state("dinov3_vitl16_sat"), tmp_path / "a.pth")
    with pytest.raises(
        WeightsError,
        match=r"holds the weights of dinov3_vitl16_sat \(.*with local_cls_norm.\*\), not of "
        r"dinov3_vitl16: build dinov3_vitl16_sat for it \(inputs normalised with mean \(0.43,",
    ):
        build_backbone("dinov3_vitl16", weights=sat, **TINY_V3)
    web = saved(_state("dinov3_vitl16"), tmp_path / "b.pth")
    with pytest.raises(
        WeightsError,
        match=r"holds the weights of dinov3_vitl16 \(.*without local_cls_norm.\*\), not of "
        r"dinov3_vitl16_sat: build dinov3_vitl16 for it \(inputs normalised with mean \(0.485,",
    ):
        build_backbone("dinov3_vitl16_sat", weights=web, **TINY_V3)


@pytest.mark.parametrize(
    ("file", "name", "owner"),
    [
        ("dinov3_vit7b16_pretrain_sat493m-a6675841.pth", "dinov3_vit7b16", "dinov3_vit7b16_sat"),
        ("dinov3_vit7b16_pretrain_lvd1689m-a955f4ea.pth", "dinov3_vit7b16_sat", "dinov3_vit7b16"),
    ],
)
def test_file_name_hash_names_the_right_backbone(tmp_path, file, name, owner):
    # Both 7B files have the same keys and shapes (local_cls_norm included): only the name tells.
    path = saved(_state(name), tmp_path / file)
    with pytest.raises(WeightsError, match=rf"official file of {owner} .* build {owner} for it"):
        build_backbone(name, weights=path, **TINY_V3)
    build_backbone(owner, weights=saved(_state(owner), tmp_path / "ok" / file), **TINY_V3)
    # Behind a link with a name that says nothing, the link's target still tells.
    link = tmp_path / "link" / "dinov3_7b.pth"
    link.parent.mkdir()
    link.symlink_to(path)
    with pytest.raises(WeightsError, match=rf"official file of {owner} .* build {owner} for it"):
        build_backbone(name, weights=link, **TINY_V3)


def test_a_name_the_tensors_contradict_does_not_send_each_backbone_to_the_other(tmp_path):
    """A web ViT-L file renamed like the SAT-493M one: its keys (no local_cls_norm) decide. It
    loads as the web model, and the SAT model refuses it naming the web one, not the reverse."""
    path = saved(_state("dinov3_vitl16"), tmp_path / "dinov3_vitl16_pretrain_sat493m-eadcf0ff.pth")
    build_backbone("dinov3_vitl16", weights=path, **TINY_V3)
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vitl16_sat", weights=path, **TINY_V3)
    message = str(err.value)
    assert "holds the weights of dinov3_vitl16 (" in message
    assert "build dinov3_vitl16 for it" in message
    assert "is the official file of dinov3_vitl16_sat, which its tensors contradict" in message
    # S-shaped tensors named with S+'s hash: the name is wrong, the tensors fit the S chosen.
    small = saved(_state("dinov3_vits16"), tmp_path / "renamed-4057cbaa.pth")
    build_backbone("dinov3_vits16", weights=small, **TINY_V3)
    with pytest.raises(
        WeightsError, match=r"holds the weights of dinov3_vits16 .*not of dinov3_vits16plus"
    ):
        build_backbone("dinov3_vits16plus", weights=small, **TINY_V3)


def test_rope_periods_must_be_the_official_ones(tmp_path):
    state = _state()
    state["rope_embed.periods"] = state["rope_embed.periods"] * 2
    with pytest.raises(WeightsError, match=r"rope_embed.periods .* differ from base 100"):
        build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "w.pth"), **TINY_V3)


def test_official_weights_are_licence_gated():
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vitl16_sat", weights="official", **TINY_V3)
    message = str(err.value)
    assert "\n" not in message
    assert "licence-gated" in message
    assert "https://ai.meta.com/resources/models-and-libraries/dinov3-downloads/" in message
    assert "dinov3_vitl16_pretrain_sat493m-eadcf0ff.pth" in message and "path" in message
    with pytest.raises(WeightsError, match="licence-gated"):
        official_url("dinov3_vits16")


def test_7b_memory_error_before_allocation(monkeypatch):
    from claravid.infra import memory

    monkeypatch.setattr(
        memory, "_read_meminfo", lambda: "MemTotal: 8000000 kB\nMemAvailable: 2097152 kB\n"
    )
    # Record every Linear built and never fill a tensor: should the check ever come after the
    # allocation, the 27 GB stay untouched (lazily committed) and the assertion below fails.
    allocated = []
    monkeypatch.setattr(torch.nn.Linear, "reset_parameters", lambda self: allocated.append(self))
    monkeypatch.setattr(torch.nn.init, "trunc_normal_", lambda t, *a, **k: t)
    monkeypatch.setattr(torch.nn.init, "normal_", lambda t, *a, **k: t)
    with pytest.raises(NotEnoughMemoryError) as err:
        build_model("dinov3_vit7b16", num_classes=3)
    message = str(err.value)
    # 6.716 billion float32 parameters: 25.0 GiB; MemAvailable 2097152 kB = 2.0 GiB.
    assert "dinov3_vit7b16 (float32) needs 25.0 GiB" in message
    assert "only 2.0 GiB are available" in message
    # Only the meta-device count ran (its Linear layers have no storage).
    assert allocated and all(m.weight.device.type == "meta" for m in allocated)


def test_memory_check_is_skipped_when_unknown(monkeypatch):
    from claravid.infra import memory
    from claravid.models.backbones.memory import check_memory

    monkeypatch.setattr(memory, "_read_meminfo", lambda: None)
    assert memory.available_memory() is None
    check_memory(1 << 60, "anything")  # unknown: no refusal
    monkeypatch.setattr(memory, "_read_meminfo", lambda: "MemAvailable:   1024 kB\n")
    assert memory.available_memory() == 1 << 20
    build_backbone("dinov3_vits16", embed_dim=8, depth=1, num_heads=2)  # 10 KiB: fits

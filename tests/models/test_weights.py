"""Weight files: official .pth, Hugging Face safetensors, mismatches, the official download."""

import urllib.error

import pytest
import torch
from safetensors.torch import save_file

from models import WeightsError, build_backbone, hf_to_official, official_to_hf, official_url
from models.weights import official_checkpoint_path
from tests.models.reference import random_official_state

TINY = {"embed_dim": 32, "depth": 2, "num_heads": 2, "img_size": 28}


def _official_state(name="dinov2_vits14_reg", **extra):
    return random_official_state(build_backbone(name, **{**TINY, **extra}), seed=3)


def test_official_pth_loads_exactly(tmp_path):
    state = _official_state()
    torch.save(state, tmp_path / "w.pth")
    model = build_backbone("dinov2_vits14_reg", weights=tmp_path / "w.pth", **TINY)
    for key, value in model.state_dict().items():
        assert torch.equal(value, state[key]), key
    assert not model.training


def test_hf_names_and_qkv_split():
    state = _official_state("dinov2_vitg14")
    hf = official_to_hf(state)
    d = 32
    assert hf["embeddings.position_embeddings"].shape == (1, 5, d)
    assert "embeddings.register_tokens" not in hf  # giant without registers
    q = hf["encoder.layer.1.attention.attention.query.weight"]
    k = hf["encoder.layer.1.attention.attention.key.bias"]
    v = hf["encoder.layer.1.attention.attention.value.weight"]
    assert torch.equal(q, state["blocks.1.attn.qkv.weight"][:d])
    assert torch.equal(k, state["blocks.1.attn.qkv.bias"][d : 2 * d])
    assert torch.equal(v, state["blocks.1.attn.qkv.weight"][2 * d :])
    assert torch.equal(hf["encoder.layer.0.layer_scale2.lambda1"], state["blocks.0.ls2.gamma"])
    assert torch.equal(
        hf["encoder.layer.0.mlp.weights_in.weight"], state["blocks.0.mlp.w12.weight"]
    )
    assert torch.equal(hf["layernorm.bias"], state["norm.bias"])
    assert not any(k.startswith("blocks.") for k in hf)


@pytest.mark.parametrize("name", ["dinov2_vits14", "dinov2_vits14_reg", "dinov2_vitg14"])
def test_hf_round_trip(name):
    state = _official_state(name)
    back = hf_to_official(official_to_hf(state))
    assert set(back) == set(state)
    for key in state:
        assert torch.equal(back[key], state[key]), key


def test_hf_safetensors_gives_same_outputs_as_pth(tmp_path):
    state = _official_state()
    torch.save(state, tmp_path / "w.pth")
    # Hugging Face classification models prefix the backbone with "dinov2."
    hf = {f"dinov2.{k}": v.contiguous() for k, v in official_to_hf(state).items()}
    hf["classifier.weight"] = torch.zeros(3, 64)
    save_file(hf, str(tmp_path / "model.safetensors"))
    a = build_backbone("dinov2_vits14_reg", weights=tmp_path / "w.pth", **TINY)
    b = build_backbone("dinov2_vits14_reg", weights=tmp_path / "model.safetensors", **TINY)
    x = torch.randn(2, 3, 42, 28)
    torch.testing.assert_close(a.get_intermediate_layers(x, 2), b.get_intermediate_layers(x, 2))


def test_wrong_keys_are_listed(tmp_path):
    state = _official_state()
    state["blocks.0.attn.qkv_extra.weight"] = state.pop("blocks.0.attn.qkv.weight")
    state["norm.weight"] = torch.ones(7)
    torch.save(state, tmp_path / "bad.pth")
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov2_vits14_reg", weights=tmp_path / "bad.pth", **TINY)
    message = str(err.value)
    assert "missing keys (1): blocks.0.attn.qkv.weight" in message
    assert "unexpected keys (1): blocks.0.attn.qkv_extra.weight" in message
    assert "norm.weight: file (7,) vs model (32,)" in message


def test_registers_mismatch_names_register_tokens(tmp_path):
    torch.save(_official_state("dinov2_vits14"), tmp_path / "noreg.pth")
    with pytest.raises(WeightsError, match=r"(?s)missing keys \(1\): register_tokens.*_reg"):
        build_backbone("dinov2_vits14_reg", weights=tmp_path / "noreg.pth", **TINY)


def test_incomplete_hf_qkv(tmp_path):
    hf = official_to_hf(_official_state())
    del hf["encoder.layer.0.attention.attention.value.bias"]
    with pytest.raises(WeightsError, match=r"block 0: attention bias lacks \['value'\]"):
        hf_to_official(hf)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope.pth not found.*'official'"):
        build_backbone("dinov2_vits14", weights=tmp_path / "nope.pth", **TINY)
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(WeightsError, match=r"cannot read .*junk.pth"):
        build_backbone("dinov2_vits14", weights=tmp_path / "junk.pth", **TINY)


def test_official_urls():
    base = "https://dl.fbaipublicfiles.com/dinov2"
    assert official_url("dinov2_vitl14") == f"{base}/dinov2_vitl14/dinov2_vitl14_pretrain.pth"
    assert official_url("dinov2_vitg14_reg") == (
        f"{base}/dinov2_vitg14/dinov2_vitg14_reg4_pretrain.pth"
    )


def test_official_offline_names_url_and_place(monkeypatch):
    def offline(url, dst, progress=True):
        raise urllib.error.URLError("no network")

    monkeypatch.setattr(torch.hub, "download_url_to_file", offline)
    target = official_checkpoint_path("dinov2_vits14")
    with pytest.raises(ConnectionError) as err:
        build_backbone("dinov2_vits14", weights="official")
    assert official_url("dinov2_vits14") in str(err.value)
    assert str(target) in str(err.value)


def test_official_uses_the_hub_cache(monkeypatch):
    # A file already in the cache is used as is: no download is attempted.
    def forbidden(*args, **kwargs):
        raise AssertionError("must not download")

    monkeypatch.setattr(torch.hub, "download_url_to_file", forbidden)
    state = _official_state("dinov2_vits14")
    target = official_checkpoint_path("dinov2_vits14")
    target.parent.mkdir(parents=True, exist_ok=True)
    torch.save(state, target)
    model = build_backbone("dinov2_vits14", weights="official", **TINY)
    assert torch.equal(model.pos_embed, state["pos_embed"])

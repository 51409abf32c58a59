"""Weight files: official .pth, Hugging Face safetensors, mismatches, the official download."""

import urllib.error

import pytest
import torch
from safetensors.torch import save_file

from claravid.models import WeightsError, build_backbone, official_url
from claravid.models.weights.loader import official_checkpoint_path
from tests.helpers.files import unreadable_files
from tests.helpers.weights import dinov2_from_hugging_face, dinov2_to_hugging_face
from tests.models.backbones.reference import random_official_state
from tests.tiny import VIT_2 as TINY


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
    hf = dinov2_to_hugging_face(state)
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
    back = dinov2_from_hugging_face(dinov2_to_hugging_face(state))
    assert set(back) == set(state)
    for key in state:
        assert torch.equal(back[key], state[key]), key


def test_hf_safetensors_gives_same_outputs_as_pth(tmp_path):
    state = _official_state()
    torch.save(state, tmp_path / "w.pth")
    # Hugging Face classification models prefix the backbone with "dinov2."
    hf = {f"dinov2.{k}": v.contiguous() for k, v in dinov2_to_hugging_face(state).items()}
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
    with pytest.raises(
        WeightsError,
        match=r"holds the weights of dinov2_vits14 \(32 wide, 2 blocks, MLP, patch 14\), not of "
        r"dinov2_vits14_reg: build dinov2_vits14 for it",
    ):
        build_backbone("dinov2_vits14_reg", weights=tmp_path / "noreg.pth", **TINY)


def test_incomplete_hf_qkv(tmp_path):
    hf = dinov2_to_hugging_face(_official_state())
    del hf["encoder.layer.0.attention.attention.value.bias"]
    with pytest.raises(
        WeightsError,
        match=r"has part of blocks.0.attn.qkv.bias but lacks "
        r"encoder.layer.0.attention.attention.value.bias: the file is incomplete",
    ):
        dinov2_from_hugging_face(hf)


def test_missing_and_unreadable_files(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope.pth not found.*'official'"):
        build_backbone("dinov2_vits14", weights=tmp_path / "nope.pth", **TINY)
    with pytest.raises(WeightsError, match=r"holds no weights file \(\*.safetensors"):
        build_backbone("dinov2_vits14", weights=tmp_path, **TINY)


def test_unreadable_weights_name_the_file_and_never_advise_unsafe_loading(tmp_path):
    files = unreadable_files(tmp_path)
    assert len(files) == 6
    for path, match in files.items():
        with pytest.raises(WeightsError) as info:
            build_backbone("dinov2_vits14", weights=path, **TINY)
        message = str(info.value)
        assert str(path) in message and match in message, message
        assert "weights_only" not in message and "likely succeed" not in message
    torch.save({"pos_embed": "text"}, tmp_path / "strings.pth")
    with pytest.raises(WeightsError, match=r"not a state dict of tensors.*pos_embed"):
        build_backbone("dinov2_vits14", weights=tmp_path / "strings.pth", **TINY)


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


def _hf_layer_keys(i: int, ffn: tuple[str, str]) -> list[str]:
    """The parameters of layer ``i`` of transformers' ``Dinov2Model``, written out by hand."""
    names = [
        "norm1.weight",
        "norm1.bias",
        "attention.attention.query.weight",
        "attention.attention.query.bias",
        "attention.attention.key.weight",
        "attention.attention.key.bias",
        "attention.attention.value.weight",
        "attention.attention.value.bias",
        "attention.output.dense.weight",
        "attention.output.dense.bias",
        "layer_scale1.lambda1",
        "norm2.weight",
        "norm2.bias",
        f"mlp.{ffn[0]}.weight",
        f"mlp.{ffn[0]}.bias",
        f"mlp.{ffn[1]}.weight",
        f"mlp.{ffn[1]}.bias",
        "layer_scale2.lambda1",
    ]
    return [f"encoder.layer.{i}.{n}" for n in names]


# The real state-dict keys of Hugging Face ``Dinov2Model`` (transformers modeling_dinov2.py:
# Dinov2Embeddings, Dinov2Layer with Dinov2Attention{attention, output.dense}, Dinov2LayerScale
# .lambda1, Dinov2MLP fc1/fc2 or Dinov2SwiGLUFFN weights_in/weights_out, final layernorm) and of
# ``Dinov2WithRegistersModel`` (adds embeddings.register_tokens). Not derived from our tables.
HF_EMBEDDINGS = [
    "embeddings.cls_token",
    "embeddings.mask_token",
    "embeddings.position_embeddings",
    "embeddings.patch_embeddings.projection.weight",
    "embeddings.patch_embeddings.projection.bias",
]
HF_FINAL = ["layernorm.weight", "layernorm.bias"]
MLP, SWIGLU = ("fc1", "fc2"), ("weights_in", "weights_out")
HF_KEYS = {
    "dinov2_vits14": [*HF_EMBEDDINGS, *_hf_layer_keys(0, MLP), *_hf_layer_keys(1, MLP), *HF_FINAL],
    "dinov2_vits14_reg": [
        *HF_EMBEDDINGS,
        "embeddings.register_tokens",
        *_hf_layer_keys(0, MLP),
        *_hf_layer_keys(1, MLP),
        *HF_FINAL,
    ],
    "dinov2_vitg14": [
        *HF_EMBEDDINGS,
        *_hf_layer_keys(0, SWIGLU),
        *_hf_layer_keys(1, SWIGLU),
        *HF_FINAL,
    ],
}


@pytest.mark.parametrize("name", sorted(HF_KEYS))
def test_converter_writes_the_real_hugging_face_key_names(name):
    state = _official_state(name)
    hf = dinov2_to_hugging_face(state)
    assert (
        len(HF_KEYS[name]) == len(set(HF_KEYS[name])) == len(state) + 2 * 4
    )  # per layer qkv.{weight,bias} -> q, k, v
    assert sorted(hf) == sorted(HF_KEYS[name])
    d = TINY["embed_dim"]
    assert hf["encoder.layer.1.attention.output.dense.weight"].shape == (d, d)
    assert torch.equal(
        hf["encoder.layer.1.attention.output.dense.bias"], state["blocks.1.attn.proj.bias"]
    )
    assert torch.equal(hf["embeddings.position_embeddings"], state["pos_embed"])


def test_file_with_the_real_hugging_face_names_loads(tmp_path):
    """A state dict keyed by the hand-written names (not by our converter) loads exactly."""
    d, hidden = TINY["embed_dim"], 4 * TINY["embed_dim"]
    g = torch.Generator().manual_seed(0)
    special = {
        "embeddings.cls_token": (1, 1, d),
        "embeddings.mask_token": (1, d),
        "embeddings.position_embeddings": (1, 5, d),
        "embeddings.patch_embeddings.projection.weight": (d, 3, 14, 14),
    }

    def shape(key):
        if key in special:
            return special[key]
        if "mlp.fc1" in key:
            return (hidden, d) if key.endswith("weight") else (hidden,)
        if "mlp.fc2.weight" in key:
            return (d, hidden)
        if key.endswith("bias") or "norm" in key or key.endswith("lambda1"):
            return (d,)
        return (d, d)

    hf = {key: torch.randn(shape(key), generator=g) for key in HF_KEYS["dinov2_vits14"]}
    save_file(hf, str(tmp_path / "model.safetensors"))
    model = build_backbone("dinov2_vits14", weights=tmp_path / "model.safetensors", **TINY)
    own = model.state_dict()
    for i in (0, 1):
        layer = f"encoder.layer.{i}."
        qkv = [hf[f"{layer}attention.attention.{n}.weight"] for n in ("query", "key", "value")]
        assert torch.equal(own[f"blocks.{i}.attn.qkv.weight"], torch.cat(qkv))
        assert torch.equal(
            own[f"blocks.{i}.attn.proj.weight"], hf[f"{layer}attention.output.dense.weight"]
        )
        assert torch.equal(own[f"blocks.{i}.mlp.fc1.weight"], hf[f"{layer}mlp.fc1.weight"])
        assert torch.equal(own[f"blocks.{i}.mlp.fc2.bias"], hf[f"{layer}mlp.fc2.bias"])
        assert torch.equal(own[f"blocks.{i}.ls2.gamma"], hf[f"{layer}layer_scale2.lambda1"])
    assert torch.equal(own["norm.bias"], hf["layernorm.bias"])


def test_hugging_face_dinov2_keeps_the_official_resize_not_transformers(tmp_path):
    """transformers' Dinov2Model resizes the positional table to the exact grid; the official
    models without registers scale it by (grid + 0.1) / 37. A Hugging Face folder here keeps the
    official rule: transformers' features at the trained size, other ones elsewhere."""
    transformers = pytest.importorskip("transformers")
    state = _official_state("dinov2_vits14")
    folder = tmp_path / "dinov2-small"
    transformers.Dinov2Config(
        hidden_size=32, num_hidden_layers=2, num_attention_heads=2, image_size=28, patch_size=14
    ).save_pretrained(folder)
    save_file({k: v.contiguous() for k, v in dinov2_to_hugging_face(state).items()},
              str(folder / "model.safetensors"))  # fmt: skip
    theirs = transformers.Dinov2Model.from_pretrained(folder).eval()
    ours = build_backbone("dinov2_vits14", weights=folder, **TINY)
    # transformers 5 names its modules q_proj/o_proj in memory: that spelling loads too.
    save_file(
        {k: v.contiguous() for k, v in theirs.state_dict().items()}, str(tmp_path / "r.safetensors")
    )
    runtime = build_backbone("dinov2_vits14", weights=tmp_path / "r.safetensors", **TINY)
    for size, same in (((28, 28), True), ((42, 70), False)):
        x = torch.randn(1, 3, *size, generator=torch.Generator().manual_seed(2))
        with torch.no_grad():
            want = theirs(x).last_hidden_state[:, 1:]
            got = ours.get_intermediate_layers(x, 1)[0]
            torch.testing.assert_close(runtime.get_intermediate_layers(x, 1)[0], got)
        assert bool((got - want).abs().max() <= 1e-5) == same, size

"""Where weights come from: files, folders (``save_pretrained``, hub snapshots, shards) and hub ids
through a prepared Hugging Face cache (never the network), and every way they can be wrong."""

import json
import sys

import pytest
import torch

from claravid.models import WeightsError, build_backbone, build_model, save_checkpoint
from tests.helpers.files import use_hub_cache
from tests.helpers.weights import released_state, saved
from tests.models.weights.official_v3 import to_hugging_face, to_timm
from tests.tiny import TINY_V3

transformers = pytest.importorskip("transformers")

X = torch.randn(1, 3, 48, 80, generator=torch.Generator().manual_seed(0))
SAT = "dinov3_vitl16_sat"


def _features(model):
    with torch.no_grad():
        return model.get_intermediate_layers(X, 3)


def _cached_repo(cache, repo_id, files):
    """A repository as huggingface_hub's cache holds it: refs/main -> a snapshot folder."""
    repo = cache / f"models--{repo_id.replace('/', '--')}"
    snapshot = repo / "snapshots" / "0123abcd"
    snapshot.mkdir(parents=True)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text("0123abcd")
    for name, content in files.items():
        if isinstance(content, dict) and all(torch.is_tensor(v) for v in content.values()):
            saved(content, snapshot / name)
        else:
            (snapshot / name).write_text(json.dumps(content))
    return snapshot


def _transformers_folder(state, folder, **save_args):
    """What ``DINOv3ViTModel.save_pretrained`` writes for these weights (ViT-L-like, MLP)."""
    config = transformers.DINOv3ViTConfig(
        hidden_size=TINY_V3["embed_dim"],
        num_hidden_layers=TINY_V3["depth"],
        num_attention_heads=TINY_V3["num_heads"],
        intermediate_size=4 * TINY_V3["embed_dim"],
        num_register_tokens=4,
        patch_size=16,
    )
    model = transformers.DINOv3ViTModel(config)
    model.load_state_dict(to_hugging_face(state, "model."), strict=True)
    model.save_pretrained(folder, **save_args)
    return folder


TIMM_SAT = "timm/vit_large_patch16_dinov3.sat493m"


def test_a_hub_id_reads_the_cache(tmp_path, monkeypatch):
    use_hub_cache(monkeypatch, tmp_path / "hub")
    state = released_state(SAT, seed=3)
    timm_config = {
        "architecture": "vit_large_patch16_dinov3",
        "pretrained_cfg": {"tag": "sat493m", "mean": [0.43, 0.411, 0.296]},
    }
    _cached_repo(
        tmp_path / "hub",
        TIMM_SAT,
        {
            "model.safetensors": to_timm(state, qkvb=False),
            "pytorch_model.bin": to_timm(state, qkvb=False),  # the same weights twice
            "config.json": timm_config,
        },
    )
    official = build_backbone(SAT, weights=saved(state, tmp_path / "o.pth"), **TINY_V3)
    model = build_backbone(SAT, weights=TIMM_SAT, **TINY_V3)
    torch.testing.assert_close(_features(model), _features(official), atol=0, rtol=0)
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vitl16", weights=TIMM_SAT, **TINY_V3)
    message = str(err.value)
    assert "\n" not in message
    assert f"the hub repository {TIMM_SAT} holds dinov3_vitl16_sat (SAT-493M)" in message
    assert "build dinov3_vitl16_sat for it" in message


def test_a_hub_id_offline_and_not_cached_says_what_to_download(tmp_path, monkeypatch):
    use_hub_cache(monkeypatch, tmp_path / "hub")
    repo = "timm/vit_large_patch16_dinov3.lvd1689m"
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vitl16", weights=repo, **TINY_V3)
    message = str(err.value)
    assert "\n" not in message
    assert "does not hold that repository while HF_HUB_OFFLINE is set" in message
    assert f"`hf download {repo}`" in message
    assert str(tmp_path / "hub" / "models--timm--vit_large_patch16_dinov3.lvd1689m") in message
    monkeypatch.setitem(sys.modules, "huggingface_hub", None)  # not installed
    with pytest.raises(WeightsError, match=r"needs huggingface_hub: pip install 'claravid\[hub\]'"):
        build_backbone("dinov3_vitl16", weights=repo, **TINY_V3)


def test_a_hugging_face_snapshot_folder_tells_sat_from_web(tmp_path):
    """The HF files drop local_cls_norm: the snapshot's repository folder names the weights."""
    state = released_state(SAT, seed=3)
    snapshot = _cached_repo(
        tmp_path / "hub",
        "facebook/dinov3-vitl16-pretrain-sat493m",
        {"model.safetensors": to_hugging_face(state, "model.")},
    )
    official = build_backbone(SAT, weights=saved(state, tmp_path / "o.pth"), **TINY_V3)
    for given in (snapshot, snapshot / "model.safetensors"):
        model = build_backbone(SAT, weights=given, **TINY_V3)
        torch.testing.assert_close(_features(model), _features(official), atol=0, rtol=0)
        with pytest.raises(
            WeightsError, match=r"holds dinov3_vitl16_sat .* build dinov3_vitl16_sat"
        ):
            build_backbone("dinov3_vitl16", weights=given, **TINY_V3)


def test_a_save_pretrained_folder_and_its_shards(tmp_path):
    name = "dinov3_vitl16"
    state = released_state(name, seed=3)
    official = build_backbone(name, weights=saved(state, tmp_path / "o.pth"), **TINY_V3)
    folder = _transformers_folder(state, tmp_path / "dinov3-vitl16-pretrain-lvd1689m")
    model = build_backbone(name, weights=folder, **TINY_V3)
    torch.testing.assert_close(_features(model), _features(official), atol=0, rtol=0)
    shards = _transformers_folder(state, tmp_path / "lvd1689m-shards", max_shard_size="40KB")
    names = sorted(p.name for p in shards.iterdir())
    assert "model.safetensors.index.json" in names and len(names) > 3
    model = build_backbone(name, weights=shards, **TINY_V3)
    torch.testing.assert_close(_features(model), _features(official), atol=0, rtol=0)
    shard = next(shards.glob("model-00001-of-*.safetensors"))
    with pytest.raises(
        WeightsError, match=r"is one shard of a sharded checkpoint: pass the folder"
    ):
        build_backbone(name, weights=shard, **TINY_V3)
    last = sorted(shards.glob("model-0*.safetensors"))[-1]
    last.unlink()
    with pytest.raises(WeightsError, match=rf"lists \d+ shards, and {last.name} is missing"):
        build_backbone(name, weights=shards, **TINY_V3)


@pytest.mark.parametrize(
    ("key", "value", "says"),
    [
        ("rope_theta", 10000.0, r"rope_theta 10000.0 \(the model: 100.0\)"),
        ("hidden_act", "silu", r"hidden_act 'silu' \(the model: 'gelu'\)"),
    ],
)
def test_a_config_json_of_another_architecture_is_refused(tmp_path, key, value, says):
    name = "dinov3_vitl16"
    folder = _transformers_folder(released_state(name, seed=3), tmp_path / "lvd1689m")
    config = json.loads((folder / "config.json").read_text())
    config[key] = value
    (folder / "config.json").write_text(json.dumps(config))
    with pytest.raises(WeightsError, match=rf"config.json describes another model .*{says}"):
        build_backbone(name, weights=folder, **TINY_V3)


def test_folders_without_one_weights_file(tmp_path):
    state = released_state("dinov3_vits16", seed=3)
    saved(state, tmp_path / "two" / "a.pth")
    saved(state, tmp_path / "two" / "b.safetensors")
    with pytest.raises(WeightsError, match=r"holds 2 weights files \(a.pth, b.safetensors\): pass"):
        build_backbone("dinov3_vits16", weights=tmp_path / "two", **TINY_V3)
    (tmp_path / "none").mkdir()
    with pytest.raises(WeightsError, match=r"holds no weights file"):
        build_backbone("dinov3_vits16", weights=tmp_path / "none", **TINY_V3)


def test_missing_paths_suggest_what_exists(tmp_path):
    with pytest.raises(FileNotFoundError) as err:
        build_backbone("dinov3_vitl16", weights=tmp_path / "nope.pth", **TINY_V3)
    message = str(err.value)
    assert "'official'" not in message  # itself an error for licence-gated weights
    assert "'timm/vit_large_patch16_dinov3.lvd1689m'" in message
    with pytest.raises(FileNotFoundError, match=r"'official' to download the official file"):
        build_backbone("dinov2_vits14", weights=tmp_path / "nope.pth", embed_dim=32, depth=1)


def test_wrapper_prefixes_are_removed(tmp_path):
    name = "dinov3_vits16"
    state = released_state(name, seed=3)
    want = _features(build_backbone(name, weights=saved(state, tmp_path / "o.pth"), **TINY_V3))
    ddp = {f"module.{k}": v for k, v in state.items()}  # saved from DistributedDataParallel
    segmentation = {  # a segmentation model's file: the backbone beside a head
        **{f"backbone.{k}": v for k, v in state.items()},
        "decode_head.conv_seg.weight": torch.zeros(3, 8, 1, 1),
    }
    for i, wrapped in enumerate((ddp, {"state_dict": segmentation})):
        model = build_backbone(name, weights=saved(wrapped, tmp_path / f"{i}.pth"), **TINY_V3)
        torch.testing.assert_close(_features(model), want, atol=0, rtol=0)


def test_a_claravid_checkpoint_is_not_backbone_weights(tmp_path):
    model = build_model("dinov3_vits16", num_classes=3, backbone_kwargs={**TINY_V3, "depth": 4},
                        layers=[0, 1, 2, 3], features=8, out_channels=[8, 8, 8, 8])  # fmt: skip
    path = save_checkpoint(model, tmp_path / "best.pt")
    with pytest.raises(WeightsError) as err:
        build_backbone("dinov3_vits16", weights=path, **TINY_V3)
    message = str(err.value)
    assert "is a claravid checkpoint (a trained dinov3_vits16 segmenter)" in message
    assert "LVD-1689M" not in message and "\n" not in message


@pytest.mark.parametrize("key", ["blocks.1.attn.qkv.bias_mask", "blocks.0.mlp.fc1.weight"])
def test_nan_in_a_file_is_refused(tmp_path, key):
    state = released_state("dinov3_vits16", seed=3)
    state[key] = state[key].clone()
    state[key][5] = float("nan")
    with pytest.raises(
        WeightsError, match=rf"NaN or infinite values in {key}: the file is damaged"
    ):
        build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "w.pth"), **TINY_V3)


def test_a_bias_mask_other_than_one_zero_one_is_refused(tmp_path):
    state = released_state("dinov3_vits16", seed=3)
    state["blocks.2.attn.qkv.bias_mask"] = torch.ones_like(state["blocks.2.attn.qkv.bias_mask"])
    with pytest.raises(WeightsError, match=r"blocks.2.attn.qkv.bias_mask is not 1 for the query"):
        build_backbone("dinov3_vits16", weights=saved(state, tmp_path / "w.pth"), **TINY_V3)

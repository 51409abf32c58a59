"""Weights as people really have them half-way: interrupted hub downloads, a copied cache
repository folder, caches found the way ``huggingface_hub`` finds them, and files that are not
what their names say. Each is read, or refused in one `WeightsError` line saying what to do."""

import json
import os
import subprocess
import sys

import pytest
import torch
from safetensors.torch import save_file

from claravid.models import WeightsError, build_backbone
from tests.helpers.files import use_hub_cache
from tests.helpers.weights import released_state, saved
from tests.models.weights.test_sources import (
    TIMM_SAT,
    _cached_repo,
    _features,
    _transformers_folder,
)
from tests.tiny import TINY_V3

SAT = "dinov3_vitl16_sat"
TIMM_CONFIG = {"architecture": "vit_large_patch16_dinov3", "pretrained_cfg": {"tag": "sat493m"}}


def _one_line(info):
    message = str(info.value)
    assert "\n" not in message, message
    return message


@pytest.fixture
def sat(tmp_path):
    """A released-style SAT state and the backbone built from it as an official file."""
    state = released_state(SAT, seed=3)
    official = build_backbone(SAT, weights=saved(state, tmp_path / "o.pth"), **TINY_V3)
    return state, _features(official)


def test_the_repository_folder_of_the_cache_is_read_through_refs_main(tmp_path, sat):
    state, want = sat
    from tests.models.weights.official_v3 import to_timm

    files = {"model.safetensors": to_timm(state, qkvb=False), "config.json": TIMM_CONFIG}
    snapshot = _cached_repo(tmp_path / "copied", TIMM_SAT, files)
    repo = snapshot.parent.parent  # models--timm--vit_large_patch16_dinov3.sat493m
    model = build_backbone(SAT, weights=repo, **TINY_V3)  # before: "holds no weights file"
    torch.testing.assert_close(_features(model), want, atol=0, rtol=0)
    (repo / "refs" / "main").write_text("feedbeef")
    with pytest.raises(WeightsError) as err:
        build_backbone(SAT, weights=repo, **TINY_V3)
    assert "refs/main names the snapshot feedbeef" in _one_line(err)
    assert f"`hf download {TIMM_SAT}`" in str(err.value)


@pytest.mark.parametrize("left", ["dangling link", "config only"])
def test_an_interrupted_download_says_so_and_how_to_resume(tmp_path, monkeypatch, sat, left):
    cache = use_hub_cache(monkeypatch, tmp_path / "hub")
    snapshot = _cached_repo(cache, TIMM_SAT, {"config.json": TIMM_CONFIG})
    if left == "dangling link":  # the blob never arrived
        (snapshot / "model.safetensors").symlink_to(cache / "blobs" / "0badc0de")
    for given in (TIMM_SAT, str(snapshot)):
        with pytest.raises(WeightsError) as err:
            build_backbone(SAT, weights=given, **TINY_V3)
        message = _one_line(err)
        assert "the download is incomplete" in message
        assert f"resume it with `hf download {TIMM_SAT}`" in message or given == str(snapshot)


@pytest.mark.parametrize("variable", ["XDG_CACHE_HOME", "HUGGINGFACE_HUB_CACHE"])
def test_the_cache_is_where_huggingface_hub_puts_it(tmp_path, variable):
    # Before: only HF_HUB_CACHE and HF_HOME were read. A fresh process: huggingface_hub reads
    # the environment when imported.
    pytest.importorskip("huggingface_hub")
    read = ("HF_HUB_CACHE", "HF_HOME", "XDG_CACHE_HOME", "HUGGINGFACE_HUB_CACHE")
    env = {k: v for k, v in os.environ.items() if k not in read}
    env[variable] = str(tmp_path / "cache")
    code = ("from huggingface_hub import constants; "
            "from claravid.models.weights.hub import hub_cache_dir; "
            "print(hub_cache_dir()); print(constants.HF_HUB_CACHE)")  # fmt: skip
    ours, theirs = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                                  capture_output=True, text=True).stdout.split()  # fmt: skip
    expected = tmp_path / "cache" / ("huggingface/hub" if variable == "XDG_CACHE_HOME" else "")
    assert ours == theirs == str(expected).rstrip("/")


def test_hub_cache_dir_without_huggingface_hub_follows_the_same_order(monkeypatch, tmp_path):
    from claravid.models.weights.hub import hub_cache_dir

    monkeypatch.setitem(sys.modules, "huggingface_hub", None)
    for name in ("HF_HUB_CACHE", "HF_HOME", "HUGGINGFACE_HUB_CACHE"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert hub_cache_dir() == tmp_path / "xdg" / "huggingface" / "hub"
    monkeypatch.setenv("HUGGINGFACE_HUB_CACHE", str(tmp_path / "legacy"))
    assert hub_cache_dir() == tmp_path / "legacy"
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "new"))
    assert hub_cache_dir() == tmp_path / "new"


def test_a_shard_index_with_an_empty_weight_map_is_refused(tmp_path):
    (tmp_path / "model.safetensors.index.json").write_text(json.dumps({"weight_map": {}}))
    with pytest.raises(WeightsError) as err:  # before: IndexError
        build_backbone(SAT, weights=tmp_path, **TINY_V3)
    assert "lists no shards (its weight_map is empty)" in _one_line(err)


@pytest.mark.parametrize(
    ("config", "says"),
    [("{not json", "is not readable JSON"),
     ('["a", "list"]', "holds a JSON list, not an object"),
     ({"model_type": "vit"}, "says model_type 'vit', not a DINOv3 ViT (dinov3_vit)"),
     ({"hidden_size": "64"}, "hidden_size is the string '64', where transformers reads a int")],
)  # fmt: skip
def test_a_config_json_that_says_nothing_usable_is_refused(tmp_path, config, says):
    # Before: ignored silently (the docs say it is checked), or "hidden_size '64' (the model:
    # 64)", which reads as two equal values.
    name = "dinov3_vitl16"
    folder = _transformers_folder(released_state(name, seed=3), tmp_path / "lvd1689m")
    if isinstance(config, dict):
        config = json.dumps({**json.loads((folder / "config.json").read_text()), **config})
    (folder / "config.json").write_text(config)
    with pytest.raises(WeightsError) as err:
        build_backbone(name, weights=folder, **TINY_V3)
    assert says in _one_line(err)


@pytest.mark.parametrize("suffix", [".bin", ".pth"])
def test_a_safetensors_file_under_another_name_is_read(tmp_path, sat, suffix):
    state, want = sat
    path = tmp_path / f"weights{suffix}"
    save_file({k: v.contiguous() for k, v in state.items()}, str(path))
    model = build_backbone(SAT, weights=path, **TINY_V3)  # before: "pop from empty list"
    torch.testing.assert_close(_features(model), want, atol=0, rtol=0)


def test_empty_weights_name_nothing(tmp_path, monkeypatch, sat):
    monkeypatch.chdir(tmp_path)  # holds o.pth: "" used to read the current folder
    for given in ("", "  "):
        with pytest.raises(WeightsError) as err:
            build_backbone(SAT, weights=given, **TINY_V3)
        assert _one_line(err).startswith(f"weights={given!r} names nothing: pass an existing")


def test_meta_tensors_are_refused_as_weights(tmp_path):
    with torch.device("meta"):
        empty = build_backbone(SAT, **TINY_V3)
    path = tmp_path / "empty.pth"
    torch.save(empty.state_dict(), path)
    with pytest.raises(WeightsError) as err:  # before: a bare RuntimeError from Tensor.item()
        build_backbone(SAT, weights=path, **TINY_V3)
    assert "holds tensors without values (on the meta device" in _one_line(err)

"""``model.weights=`` takes what the Python API takes: a hub id read through a prepared Hugging Face
cache (never the network) and a folder holding the weights, and the checkpoint that training
writes rebuilds from the same source for evaluation, export and prediction."""

import pytest
import torch

from claravid.models import build_backbone, load_checkpoint
from claravid.train.cli import main as train_main
from tests.helpers.files import use_hub_cache
from tests.helpers.weights import saved
from tests.models.weights.official_v3 import released_v3_state, to_timm
from tests.models.weights.test_sources import _cached_repo
from tests.tiny import VIT, tiny_v3

SAT = "dinov3_vitl16_sat"
TIMM_SAT = "timm/vit_large_patch16_dinov3.sat493m"
TIMM_CONFIG = {"architecture": "vit_large_patch16_dinov3", "pretrained_cfg": {"tag": "sat493m"}}


@pytest.mark.parametrize("given", ["hub id", "snapshot folder"])
def test_training_reads_a_hub_id_and_a_weights_folder(
    claravid_root, tmp_path, monkeypatch, capsys, given
):
    use_hub_cache(monkeypatch, tmp_path / "hub")
    state = released_v3_state(build_backbone(SAT, **VIT), SAT, seed=5)
    files = {"model.safetensors": to_timm(state, qkvb=False), "config.json": TIMM_CONFIG}
    snapshot = _cached_repo(tmp_path / "hub", TIMM_SAT, files)
    weights = TIMM_SAT if given == "hub id" else str(snapshot)
    out = tmp_path / "run"
    argv = ["--config", "demo",
            *tiny_v3(claravid_root, out, f"model.weights={weights}", "train.steps=1",
                     "model.freeze_backbone=true",
                     "val.every=0", backbone=SAT)]  # fmt: skip
    assert train_main(argv) == 0, capsys.readouterr().err
    # Recorded as given (a hub id is no path to make absolute): evaluation, export and
    # prediction rebuild the backbone from the same source through load_checkpoint.
    checkpoint = torch.load(out / "last.pt", weights_only=True)
    assert checkpoint["model_args"]["weights"] == weights
    official = build_backbone(SAT, weights=saved(state, tmp_path / "official.pth"), **VIT)
    backbone = load_checkpoint(out / "last.pt").backbone
    x = torch.randn(1, 3, 32, 48, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        got, want = backbone.get_intermediate_layers(x, 2), official.get_intermediate_layers(x, 2)
    torch.testing.assert_close(got, want, atol=0, rtol=0)

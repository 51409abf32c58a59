"""Model checkpoints: weights_only-safe, atomic, rebuilt from the file alone."""

import pytest
import torch

from claravid.models import CheckpointError, build_model, load_checkpoint, save_checkpoint
from tests.models.backbones.reference import random_official_state
from tests.tiny import VIT
from tests.tiny import VIT_56 as TINY
from tests.tiny import WIDE_HEAD as HEAD


def _outputs(model, x):
    with torch.no_grad():
        return model.eval()(x)


def test_round_trip_random_backbone(tmp_path):
    model = build_model("dinov2_vits14_reg", num_classes=4, backbone_kwargs=TINY, **HEAD)
    path = save_checkpoint(model, tmp_path / "run" / "m.pt", epoch=3, optim={"lr": 0.1})
    ckpt = torch.load(path, weights_only=True)
    assert ckpt["format"] == "claravid-model" and ckpt["version"] == 1
    assert ckpt["epoch"] == 3 and ckpt["optim"] == {"lr": 0.1}
    assert "backbone.pos_embed" in ckpt["model"]  # a random init is always stored
    assert [p.name for p in path.parent.iterdir()] == ["m.pt"]  # no temp file left
    loaded = load_checkpoint(path)
    assert loaded.model_args == model.model_args
    x = torch.randn(1, 3, 42, 56)
    torch.testing.assert_close(_outputs(loaded, x), _outputs(model, x), atol=0, rtol=0)


def test_backbone_from_weights_file_is_referenced(tmp_path):
    weights = tmp_path / "dino.pth"
    torch.save(random_official_state(build_model(backbone_kwargs=TINY, **HEAD).backbone), weights)
    model = build_model("dinov2_vitl14", 3, weights=weights, backbone_kwargs=TINY, **HEAD)
    path = save_checkpoint(model, tmp_path / "m.pt")
    ckpt = torch.load(path, weights_only=True)
    assert not any(k.startswith("backbone.") for k in ckpt["model"])
    assert ckpt["model_args"]["weights"] == str(weights)
    x = torch.randn(1, 3, 28, 42)
    torch.testing.assert_close(_outputs(load_checkpoint(path), x), _outputs(model, x))
    full = save_checkpoint(model, tmp_path / "full.pt", include_backbone=True)
    weights.unlink()  # a self-contained file no longer needs the weights file
    torch.testing.assert_close(_outputs(load_checkpoint(full), x), _outputs(model, x))
    with pytest.raises(FileNotFoundError, match=r"dino.pth not found"):
        load_checkpoint(path)


def test_save_errors(tmp_path):
    model = build_model("dinov2_vits14", 2, backbone_kwargs=TINY, **HEAD)
    with pytest.raises(ValueError, match=r"random init.*include_backbone=True"):
        save_checkpoint(model, tmp_path / "m.pt", include_backbone=False)
    with pytest.raises(ValueError, match=r"extra entries \['model'\] are reserved"):
        save_checkpoint(model, tmp_path / "m.pt", model={})


def test_foreign_and_newer_files(tmp_path):
    torch.save({"pos_embed": torch.zeros(1)}, tmp_path / "dino.pth")
    with pytest.raises(CheckpointError, match=r"not a claravid model checkpoint.*build_model"):
        load_checkpoint(tmp_path / "dino.pth")
    model = build_model("dinov2_vits14", 2, backbone_kwargs=TINY, **HEAD)
    path = save_checkpoint(model, tmp_path / "m.pt")
    ckpt = torch.load(path, weights_only=True)
    ckpt["version"] = 2
    torch.save(ckpt, tmp_path / "new.pt")
    with pytest.raises(CheckpointError, match=r"version 2, newer than this code's 1"):
        load_checkpoint(tmp_path / "new.pt")
    (tmp_path / "junk.pt").write_text("hello")
    with pytest.raises(CheckpointError, match=r"cannot read .*junk.pt"):
        load_checkpoint(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError, match=r"checkpoint .*missing.pt not found"):
        load_checkpoint(tmp_path / "missing.pt")


def test_unreadable_checkpoints_name_the_file(tmp_path):
    from tests.helpers.files import unreadable_files

    files = unreadable_files(tmp_path)
    for path, match in files.items():
        with pytest.raises(CheckpointError) as info:
            load_checkpoint(path)
        message = str(info.value)
        assert str(path) in message and match in message, message
        assert "weights_only" not in message and "likely succeed" not in message
    with pytest.raises(CheckpointError, match="is a folder"):
        load_checkpoint(tmp_path)


def test_damaged_checkpoint_entries(tmp_path):
    model = build_model("dinov2_vits14", 2, backbone_kwargs=TINY, **HEAD)
    ckpt = torch.load(save_checkpoint(model, tmp_path / "m.pt"), weights_only=True)
    damaged = {
        "args_list": ({**ckpt, "model_args": [1]}, "'model_args' and 'model' must be dicts"),
        "unknown_arg": (
            {**ckpt, "model_args": {**ckpt["model_args"], "colour": 1}},
            "model_args that build_model rejects",
        ),
        "shape": (
            {**ckpt, "model": {**ckpt["model"], "head.head.2.bias": torch.zeros(7)}},
            r"head.head.2.bias: file \(7,\) vs model \(2,\)",
        ),
        "not_tensors": ({**ckpt, "model": {"a": 1}}, "not tensors"),
    }
    for name, (payload, match) in damaged.items():
        torch.save(payload, tmp_path / f"{name}.pt")
        with pytest.raises(CheckpointError, match=match):
            load_checkpoint(tmp_path / f"{name}.pt")


def test_checkpoint_written_before_dinov3_support_loads_with_identical_outputs(tmp_path):
    """A checkpoint in the format (and key layout) of the code before the backbone descriptions:
    weights drawn from a seed in sorted key order; the logits are literals printed by that code
    (commit 1867c9d) for the same weights and input."""
    args = {"backbone": "dinov2_vits14", "num_classes": 3, "weights": None, "layers": [0, 1, 2, 3],
            "features": 16, "out_channels": [8, 16, 32, 32], "use_cls": False,
            "backbone_kwargs": TINY}  # fmt: skip
    layout = build_model(**args).state_dict()
    assert len(layout) == 121 and "backbone.pos_embed" in layout  # the old layout: 121 tensors
    g = torch.Generator().manual_seed(0)
    state = {}
    for key, value in sorted(layout.items()):
        one = (key.endswith("weight") and "norm" in key) or key.endswith("gamma")
        state[key] = (1.0 if one else 0.0) + 0.1 * torch.randn(value.shape, generator=g)
    old = {"format": "claravid-model", "version": 1, "model_args": args, "model": state,
           "backbone_included": True}  # fmt: skip
    torch.save(old, tmp_path / "old.pt")
    model = load_checkpoint(tmp_path / "old.pt")
    assert model.model_args == args
    x = torch.randn(2, 3, 42, 56, generator=torch.Generator().manual_seed(1))
    y = _outputs(model, x)
    assert y.sum().item() == pytest.approx(440.79296875, rel=1e-5)
    assert y.abs().sum().item() == pytest.approx(1746.5777587890625, rel=1e-5)
    torch.testing.assert_close(
        y[0, :, 5, 7],
        torch.tensor([0.07611444592475891, 0.19100087881088257, -0.12607447803020477]),
    )
    torch.testing.assert_close(
        y[1, :, 40, 50],
        torch.tensor([0.019106261432170868, 0.11115619540214539, -0.14984847605228424]),
    )


def test_dinov3_checkpoint_round_trip(tmp_path):
    model = build_model("dinov3_vitl16_sat", num_classes=3, backbone_kwargs=VIT, **HEAD)
    path = save_checkpoint(model, tmp_path / "m.pt")
    ckpt = torch.load(path, weights_only=True)
    assert "backbone.rope_embed.periods" in ckpt["model"]
    loaded = load_checkpoint(path)
    assert loaded.mean == (0.430, 0.411, 0.296)
    x = torch.randint(0, 256, (1, 3, 32, 48), dtype=torch.uint8)
    torch.testing.assert_close(_outputs(loaded, x), _outputs(model, x), atol=0, rtol=0)


def test_checkpoint_of_an_unknown_backbone_names_the_known_ones(tmp_path):
    model = build_model("dinov2_vits14", 2, backbone_kwargs=TINY, **HEAD)
    ckpt = torch.load(save_checkpoint(model, tmp_path / "m.pt"), weights_only=True)
    ckpt["model_args"]["backbone"] = "dinov4_vitl16"
    torch.save(ckpt, tmp_path / "future.pt")
    with pytest.raises(ValueError, match=r"unknown backbone 'dinov4_vitl16'.*dinov3_vitl16"):
        load_checkpoint(tmp_path / "future.pt")

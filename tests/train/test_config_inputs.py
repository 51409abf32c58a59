"""What the training config says about the model's inputs, when it loads: statistics that
cannot be used, and a weights path that is wrong or relative."""

import os

import pytest

from claravid.data.transforms import augment_config
from claravid.train.cli import main as train_main
from claravid.train.config import ConfigError, load_config

BASE = ["data.root=/data", "out_dir=runs/x"]


@pytest.mark.parametrize(
    ("override", "message"),
    [
        # Malformed: OmegaConf said "bad value for None (command line): Value '$VALUE' ...".
        ("data.augment.mean=[0.5,x,0.5]", "data.augment.mean=[0.5, 'x', 0.5]: three numbers"),
        ("data.augment.std=[0.2,0.2]", "data.augment.std=[0.2, 0.2]: three numbers (R, G, B)"),
        ("data.augment.mean=0.5", "data.augment.mean=0.5: three numbers (R, G, B)"),
        # Unusable values: they trained (or stopped at the first validation) before.
        ("data.augment.std=[0.2,0,0.2]", "data.augment.std=[0.2, 0.0, 0.2]: must be positive"),
        ("data.augment.std=[-0.2,0.2,0.2]", "data.augment.std=[-0.2, 0.2, 0.2]: must be positive"),
        ("data.augment.mean=[nan,0.5,0.5]", "data.augment.mean=[nan, 0.5, 0.5]: not finite"),
        ("data.augment.mean=[123.7,116.3,103.5]",
         "data.augment.mean=[123.7, 116.3, 103.5]: statistics on the 0–255 scale? they are for "
         "pixels in [0, 1]: divide them by 255"),
        ("data.augment.std=[58.4,57.1,57.4]", "std=[58.4, 57.1, 57.4]: statistics on the 0–255"),
    ],
)  # fmt: skip
def test_unusable_statistics_are_refused_when_the_config_loads(override, message, capsys):
    with pytest.raises(ConfigError) as info:
        load_config("demo", [*BASE, override])
    text = str(info.value)
    assert message in text and "$VALUE" not in text and "None" not in text, text
    # The command line: one line, exit 2, before any data is read (/data does not exist).
    assert train_main(["--config", "demo", *BASE, override]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


def test_augment_config_refuses_the_same_statistics():
    with pytest.raises(ValueError, match=r"std=\[0.2, 0.0, 0.2\]: must be positive"):
        augment_config({"std": [0.2, 0.0, 0.2]})
    with pytest.raises(ValueError, match="divide them by 255"):
        augment_config({"mean": [123.7, 116.3, 103.5]})
    assert augment_config({"mean": [0.5, 0.4, 0.3], "std": [0.2, 0.2, 0.2]}).std == (0.2,) * 3


def test_a_relative_weights_path_is_recorded_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "w.pth").touch()
    cfg = load_config("demo", [*BASE, "model.weights=w.pth"])
    # From another folder, evaluation and export read this path from the checkpoint.
    assert cfg.model.weights == str(tmp_path / "w.pth")
    home = load_config("demo", [*BASE, "model.weights=~/w.pth"]).model.weights
    assert home == os.path.join(os.path.expanduser("~"), "w.pth")
    for kept in ("null", "official"):
        assert load_config("demo", [*BASE, f"model.weights={kept}"]).model.weights in (
            None,
            "official",
        )


@pytest.mark.parametrize("kind", ["missing", "folder"])
def test_a_wrong_weights_path_is_reported_before_any_data_is_read(tmp_path, capsys, kind):
    # The data root does not exist either: the weights are named first, and nothing is written.
    weights = tmp_path / "dinov2_vits14.pth"
    if kind == "folder":
        weights.mkdir()
    out = tmp_path / "run"
    argv = ["--config", "demo", f"data.root={tmp_path / 'no-data'}", f"out_dir={out}",
            f"model.weights={weights}"]  # fmt: skip
    assert train_main(argv) == 2
    err = capsys.readouterr().err.strip()
    if kind == "missing":
        assert err == (
            f"claravid-train: error: model.weights={weights}: no such file or folder; pass the "
            "path of dinov2_vits14's .pth or .safetensors weights file or of a folder holding "
            "one, model.weights=official, a hub id such as "
            "model.weights=timm/vit_small_patch14_dinov2.lvd142m or model.weights=null (a random "
            "backbone)"
        )
    else:  # a folder is taken, as by the Python API: this one holds no weights
        assert err.startswith(
            f"claravid-train: error: model.weights={weights}: folder {weights} holds no weights "
            "file (*.safetensors, *.bin, *.pth, *.pt)"
        )
    assert not out.exists()  # no config.yaml, no label cache, no index

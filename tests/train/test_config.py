"""Config: defaults + YAML + overrides, unknown keys with suggestions, bad values, shipped names."""

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from claravid.infra.resources import shipped_file
from claravid.train.config import (
    ConfigError,
    changed_keys,
    derive_steps,
    find_config,
    load_config,
    valid_keys,
)

ROOT = Path(__file__).resolve().parents[2]


def test_required_keys_exist_under_their_names():
    keys = set(valid_keys())
    assert {"data.root", "data.num_workers", "out_dir", "seed", "train.steps"} <= keys
    assert "train.checkpoint_every" in keys
    assert "data.augment.crop_height" in keys  # the augmentation config is part of it


def test_yaml_then_overrides_typed():
    cfg = load_config("demo", ["train.steps=7", "data.num_workers=0", "seed=3", "train.lr=1e-5"])
    assert (cfg.train.steps, cfg.data.num_workers, cfg.seed) == (7, 0, 3)
    assert cfg.train.lr == pytest.approx(1e-5) and isinstance(cfg.train.lr, float)
    assert cfg.data.palette == "uavid"  # from demo.yaml
    assert cfg.train.grad_clip == 1.0  # typed default, not in demo.yaml


@pytest.mark.parametrize(
    ("override", "suggestion"),
    [
        ("train.stpes=5", "train.steps"),
        ("data.num_worker=2", "data.num_workers"),
        ("checkpoint_every=5", "train.checkpoint_every"),  # right leaf, wrong section
        ("data.augment.crop_heigth=5", "data.augment.crop_height"),
    ],
)
def test_unknown_key_names_the_closest(override, suggestion):
    with pytest.raises(ConfigError, match="unknown config key") as info:
        load_config("demo", [override])
    assert override.split("=")[0] in str(info.value)
    assert suggestion in str(info.value)


def test_unknown_key_in_a_yaml_file(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("out_dir: x\ndata:\n  root: y\n  palete: uavid\n")
    with pytest.raises(ConfigError, match=r"'data.palete'.*data.palette"):
        load_config(path)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("train.steps=abc", "train.steps"),
        ("train.lr=-1", "train.lr"),
        ("train.schedule=linear", "poly, cosine"),
        ("data.class_weights=foo", "median_frequency"),
        ("data.crops_per_frame=0", "data.crops_per_frame"),
        ("train.steps", "not key=value"),
    ],
)
def test_bad_values_name_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config("demo", [override])


def test_missing_required_key(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("data:\n  root: y\n")
    with pytest.raises(ConfigError, match="out_dir"):
        load_config(path)


def test_config_by_name_comes_from_the_packaged_copy():
    path, text = find_config("demo")
    assert path is None  # not a file path: the shipped resource
    assert text == shipped_file("demo").read_text()
    assert text == (ROOT / "configs" / "demo.yaml").read_text()
    with pytest.raises(ConfigError, match=r"shipped: .*claravid_dpt_vitl14"):
        find_config("nope")


def test_steps_rule():
    cfg = load_config("claravid_dpt_vitl14", ["data.root=/x"])
    assert cfg.train.steps is None
    assert derive_steps(cfg, 100) == 5000  # 10 × 100 clamped up
    assert derive_steps(cfg, 1234) == 12340
    assert derive_steps(cfg, 10_000) == 30000  # clamped down
    cfg.train.steps_per_frame = 2.5
    assert derive_steps(cfg, 4000) == 10000
    cfg.train.steps = 17
    assert derive_steps(cfg, 4000) == 17


def test_changed_keys_ignore_where_and_how_shown():
    a = load_config("demo")
    b = load_config("demo", ["data.num_workers=0", "data.root=/elsewhere", "log.progress=false"])
    assert changed_keys(a, b) == []
    c = load_config("demo", ["train.lr=0.1", "seed=1"])
    assert changed_keys(a, c) == ["seed", "train.lr"]
    assert OmegaConf.to_container(a) != OmegaConf.to_container(c)


def test_every_key_eval_reads_from_a_checkpoint_exists_in_the_schema():
    """eval reads a checkpoint's training config by key paths (it cannot import this schema):
    each path must name a key of the schema, so a rename here fails this test."""
    from claravid.eval.inference.sources import SPLIT_FIELDS, TRAINING_KEYS
    from claravid.models.onnx_metadata import CONFIG_KEYS

    keys = set(valid_keys())
    prefixes = {k.rsplit(".", i)[0] for k in keys for i in range(k.count(".") + 1)}
    paths = [*TRAINING_KEYS.values(), *CONFIG_KEYS, *(("data", "split", f) for f in SPLIT_FIELDS)]
    missing = [".".join(p) for p in paths if ".".join(p) not in keys | prefixes]
    assert not missing, f"keys read by eval that the training schema lacks: {missing}"
    assert "data.val_root" in keys and "val.window" in keys  # the check sees leaf keys


def test_split_settings_are_checked_by_name(tmp_path):
    # Before: seed -1 failed deep in numpy, and a single held-out mission was a type error.
    with pytest.raises(ConfigError, match=r"^data\.split\.seed must be an integer >= 0, got -1$"):
        load_config("demo", ["data.split.seed=-1"])
    with pytest.raises(ConfigError, match=r"^data\.split\.val_missions holds unknown ClaraVid"):
        load_config("demo", ["data.split.val_missions=urbn_1"])
    cfg = load_config("demo", ["data.split.test_missions=urban_high_1"])
    assert list(cfg.data.split.test_missions) == ["urban_high_1"]
    path = tmp_path / "c.yaml"
    path.write_text(
        (shipped_file("demo").read_text() + "\n").replace(
            "data:\n", "data:\n  split: {test_missions: urban_high_1}\n", 1
        )
    )
    assert list(load_config(path).data.split.test_missions) == ["urban_high_1"]

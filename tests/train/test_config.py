"""Config: defaults + YAML + overrides, unknown keys with suggestions, bad values, shipped names."""

import re
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from claravid.infra.resources import shipped_file
from claravid.train.cli import main as train_main
from claravid.train.config import (
    ConfigError,
    changed_keys,
    derive_steps,
    find_config,
    from_plain,
    load_config,
    statistics_warning,
    to_plain,
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
        ("val.tta_rule=timm", "val.tta_rule"),
        ("val.tta_scales=[0,1]", "val.tta_scales"),
        ("val.tta_size=0", "val.tta_size"),
    ],
)
def test_bad_values_name_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config("demo", [override])


def test_validation_runs_the_configured_test_time_augmentation():
    from claravid.eval import TTAConfig
    from claravid.train.loop import _val_window

    cfg = load_config("demo", ["val.tta_scales=[0.9,1.0,1.1]", "val.tta_flip=true",
                               "val.tta_rule=mmseg"])  # fmt: skip
    assert _val_window(cfg, 14, "auto").tta == TTAConfig((0.9, 1.0, 1.1), True, "mmseg")
    assert _val_window(load_config("demo"), 14, "auto").tta is None


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
    from claravid.models.export.metadata import CONFIG_KEYS

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


# Statistics and sizes follow the backbone (issue 26). The expected numbers are the published
# ones, typed here: ImageNet's and SAT-493M's (the DINOv3 satellite models' normalisation).
IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))
SAT493M = ((0.430, 0.411, 0.296), (0.213, 0.156, 0.143))


def _bare(tmp_path, backbone, *extra):
    """A config file that sets no statistics and no window (448 = 32 x 14 = 28 x 16 crops)."""
    path = tmp_path / "bare.yaml"
    path.write_text(
        "out_dir: runs/x\ndata:\n  root: /data\n  augment: {crop_height: 448, crop_width: 448}\n"
        "model: {weights: null}\n"
    )
    return load_config(path, [f"model.backbone={backbone}", *extra])


@pytest.mark.parametrize(
    ("backbone", "stats", "window"),
    [
        ("dinov2_vitl14", IMAGENET, 630),  # 45 patches of 14: the paper's window
        ("dinov3_vitl16", IMAGENET, 640),  # 40 patches of 16: the nearest that covers 630
        ("dinov3_vitl16_sat", SAT493M, 640),
        ("dinov3_vit7b16_sat", SAT493M, 640),
        ("dinov3_vits16", IMAGENET, 640),
    ],
)
def test_unset_statistics_and_window_are_the_backbone_s(tmp_path, backbone, stats, window):
    cfg = _bare(tmp_path, backbone)
    assert tuple(cfg.data.augment.mean) == stats[0] and tuple(cfg.data.augment.std) == stats[1]
    assert cfg.val.window == window
    # What checkpoints record: the resolved numbers, not null.
    plain = to_plain(cfg)
    assert (
        list(plain["data"]["augment"]["mean"]) == list(stats[0])
        and plain["val"]["window"] == window
    )


def test_statistics_and_window_given_are_kept(tmp_path):
    cfg = _bare(tmp_path, "dinov3_vitl16_sat", "data.augment.mean=[0.5,0.5,0.5]",
                "data.augment.std=[0.25,0.25,0.25]", "val.window=320")  # fmt: skip
    assert tuple(cfg.data.augment.mean) == (0.5,) * 3 and tuple(cfg.data.augment.std) == (0.25,) * 3
    assert cfg.val.window == 320
    warning = statistics_warning(cfg)
    assert "dinov3_vitl16_sat" in warning and "(0.5, 0.5, 0.5)" in warning
    assert "SAT-493M: mean (0.43, 0.411, 0.296), std (0.213, 0.156, 0.143)" in warning
    # The backbone's own numbers, named explicitly, are no reason to warn.
    same = _bare(tmp_path, "dinov3_vitl16_sat", "data.augment.mean=[0.430,0.411,0.296]",
                 "data.augment.std=[0.213,0.156,0.143]")  # fmt: skip
    assert statistics_warning(same) is None
    assert statistics_warning(_bare(tmp_path, "dinov2_vitl14")) is None
    imagenet = _bare(tmp_path, "dinov3_vitl16_sat", "data.augment.mean=[0.485,0.456,0.406]",
                     "data.augment.std=[0.229,0.224,0.225]")  # fmt: skip
    assert "(0.485, 0.456, 0.406)" in statistics_warning(imagenet)


@pytest.mark.parametrize(
    ("stats", "named"),
    [
        (["data.augment.std=[0.25,0.224,0.225]"], "std (0.25, 0.224, 0.225)"),  # std alone
        (["data.augment.mean=[0.485,0.456,0.5]"], "mean (0.485, 0.456, 0.5)"),  # mean alone
    ],
)
def test_statistics_warning_compares_mean_and_std_each(tmp_path, stats, named):
    # Each number counts: a std that differs while the mean is ImageNet's still warns.
    warning = statistics_warning(_bare(tmp_path, "dinov2_vitl14", *stats))
    assert warning is not None and named in warning
    assert "ImageNet: mean (0.485, 0.456, 0.406), std (0.229, 0.224, 0.225)" in warning


@pytest.mark.parametrize(
    ("backbone", "override", "message"),
    [
        ("dinov2_vitl14", "data.augment.crop_height=640",
         "data.augment.crop_height=640 is not a multiple of the patch size 14 of dinov2_vitl14: "
         "use 630 or 644"),
        ("dinov3_vitl16", "data.augment.crop_width=630",
         "data.augment.crop_width=630 is not a multiple of the patch size 16 of dinov3_vitl16: "
         "use 624 or 640"),
        ("dinov3_vitl16_sat", "val.window=630",
         "val.window=630 is not a multiple of the patch size 16 of dinov3_vitl16_sat: "
         "use 624 or 640"),
        ("dinov2_vits14", "val.window=10",  # below one patch: the two smallest
         "val.window=10 is not a multiple of the patch size 14 of dinov2_vits14: use 14 or 28"),
    ],
)  # fmt: skip
def test_sizes_off_the_patch_grid_name_the_two_nearest(tmp_path, capsys, backbone, override,
                                                       message):  # fmt: skip
    with pytest.raises(ConfigError, match=re.escape(message)):
        _bare(tmp_path, backbone, override)
    # The command line says it in one line, exit 2, before reading any data (there is none).
    argv = ["--config", str(tmp_path / "bare.yaml"), f"model.backbone={backbone}", override]
    assert train_main(argv) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"claravid-train: error: {message}"


def test_a_patch_size_overridden_for_a_tiny_model_is_the_one_checked(tmp_path):
    # 448 is a multiple of 14 and 16 but not of 10: 440 or 450.
    message = (
        "crop_height=448 is not a multiple of the patch size 10 of dinov3_vits16: use 440 or 450"
    )
    with pytest.raises(ConfigError, match=re.escape(message)):
        _bare(tmp_path, "dinov3_vits16", "model.backbone_kwargs.patch_size=10", "val.window=450")


@pytest.mark.parametrize(
    ("name", "file"),
    [
        ("claravid_dpt_dinov3_vitl16", "dinov3_vitl16_pretrain_lvd1689m-8aa4cbdd.pth"),
        ("claravid_dpt_dinov3_vitl16_sat", "dinov3_vitl16_pretrain_sat493m-eadcf0ff.pth"),
    ],
)
def test_dinov3_configs_need_the_weights_file_one_line(tmp_path, capsys, name, file):
    hint = f"pass model.weights=/path/to/{file}"
    for extra in ([], ["model.weights=official"]):
        with pytest.raises(ConfigError, match="licence-gated"):
            load_config(name, extra)
        assert train_main(["--config", name, *extra]) == 2
        err = capsys.readouterr().err.strip()
        timm = "timm/vit_large_patch16_dinov3." + ("sat493m" if "sat" in name else "lvd1689m")
        assert err.startswith("claravid-train: error: model.weights: ") and hint in err
        assert err.endswith(f"or timm's ungated copy: model.weights={timm}")
        assert len(err.splitlines()) == 1 and "dinov3-downloads" in err
    cfg = load_config(name, [f"model.weights={tmp_path / file}"])
    # The paper's protocol at 640: crops and windows of 40 x 40 patches of 16.
    assert (cfg.data.augment.crop_height, cfg.data.augment.crop_width, cfg.val.window) == (
        640, 640, 640)  # fmt: skip
    stats = SAT493M if name.endswith("_sat") else IMAGENET
    assert (tuple(cfg.data.augment.mean), tuple(cfg.data.augment.std)) == stats
    assert cfg.model.freeze_backbone and cfg.model.backbone == name.removeprefix("claravid_dpt_")
    # The same protocol as the DINOv2-L/14 config, but for the backbone, its weights and sizes.
    base = load_config("claravid_dpt_vitl14")
    differ = changed_keys(base, cfg)
    expected = ["data.augment.crop_height", "data.augment.crop_width", "model.backbone",
                "model.weights", "val.window"]  # fmt: skip
    if name.endswith("_sat"):
        expected += ["data.augment.mean", "data.augment.std"]
    assert differ == sorted(expected)


def test_a_config_recorded_before_the_backbone_defaults_resumes(tmp_path):
    """A run's config.yaml and checkpoints of the previous version recorded ImageNet's mean
    and std and the window as numbers: they read back, and equal today's resolved config."""
    new = load_config("demo", ["data.root=/d", "out_dir=/o"])
    old = to_plain(new)
    old["data"]["augment"]["mean"] = [0.485, 0.456, 0.406]  # what the old default wrote
    old["data"]["augment"]["std"] = [0.229, 0.224, 0.225]
    old["val"]["window"] = 224
    assert changed_keys(from_plain(old), new) == []

"""The loop on the tiny fixture: the loss goes down, outputs, faults, every shipped config."""

import json
import os
import re
import sys

import pytest
import torch

from claravid import models
from claravid.data.palettes import load_palette
from claravid.data.real_layouts import LAYOUT_DATASETS
from claravid.infra.resources import shipped_names
from claravid.models.checkpoint import read_checkpoint
from claravid.train import TrainingDiverged, load_config, train
from claravid.train.checkpoint import save_training_checkpoint
from claravid.train.cli import main
from claravid.train.config import StatisticsWarning
from tests.helpers.files import sha256
from tests.helpers.real_trees import make_tree
from tests.helpers.scoring import miou_by_hand
from tests.tiny import HEAD_OVERRIDES, tiny, tiny_v3


def rows(out):
    return [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_loss_decreases_and_run_folder_is_complete(claravid_root, tmp_path):
    out = tmp_path / "run"
    extra = ["train.steps=40", "train.lr=3e-3", "train.log_every=1", "val.every=20"]
    cfg = load_config("demo", tiny(claravid_root, out, *extra, "model.freeze_backbone=true"))
    result = train(cfg)
    losses = [r["loss"] for r in rows(out) if "loss" in r]
    assert len(losses) == 40
    assert sum(losses[-5:]) / 5 < 0.8 * sum(losses[:5]) / 5, losses
    vals = [r for r in rows(out) if "miou" in r]
    assert [r["step"] for r in vals] == [20, 40]
    assert set(vals[0]["miou_bins"]) == {"low", "medium", "high"}
    assert list(vals[0]["per_class_iou"]) == list(load_palette("uavid").names)
    assert result.best_miou == max(r["miou"] for r in vals)
    for name in ("config.yaml", "metrics.jsonl", "curves.png", "last.pt", "best.pt"):
        assert (out / name).is_file(), name
    last = read_checkpoint(out / "last.pt")  # weights_only
    assert last["step"] == 40 and last["config"]["train"]["steps"] == 40
    assert last["sampler"] == {"step": 40, "frames_seen": 160}
    assert {"optimizer", "scheduler", "scaler", "rng", "model_args"} <= set(last)
    best = read_checkpoint(out / "best.pt")
    assert best["step"] == result.best_step and best["best_miou"] == result.best_miou
    # The model rebuilds from the file alone (frozen backbone: head weights changed only).
    model = models.load_checkpoint(out / "last.pt")
    assert model.num_classes == 8


def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(claravid_root, tmp_path, capsys):
    out = tmp_path / "run"
    args = tiny(claravid_root, out, "train.steps=6", "train.lr=1e30", "train.grad_clip=0",
                "train.checkpoint_every=1", "val.every=0")  # fmt: skip
    assert main(["--config", "demo", *args]) == 1
    err = capsys.readouterr().err
    assert "stopped:" in err and ("nan" in err or "inf" in err) and "last.pt" in err
    assert "Traceback" not in err
    ckpt = read_checkpoint(out / "last.pt")
    assert 1 <= ckpt["step"] < 6
    state = models.load_checkpoint(out / "last.pt").state_dict()
    assert all(torch.isfinite(v).all() for v in state.values() if v.is_floating_point())


def test_injected_inf_stops_before_the_step(claravid_root, tmp_path, monkeypatch):
    import claravid.train.loop as loop

    real = loop.F.cross_entropy
    calls = []

    def poisoned(*args, **kwargs):
        calls.append(1)
        loss = real(*args, **kwargs)
        return loss * float("inf") if len(calls) == 3 else loss

    monkeypatch.setattr(loop.F, "cross_entropy", poisoned)
    out = tmp_path / "run"
    cfg = load_config("demo", tiny(claravid_root, out, "train.steps=5", "train.checkpoint_every=2",
                                   "val.every=0"))  # fmt: skip
    with pytest.raises(TrainingDiverged, match="at step 3"):
        train(cfg)
    assert read_checkpoint(out / "last.pt")["step"] == 2


def test_user_mistakes_are_one_line_exit_2(claravid_root, tmp_path, capsys):
    cases = {
        "data.root": tiny(tmp_path / "nowhere", tmp_path / "a"),
        # Both missions held out: the train split is empty.
        "holds no frame": tiny(
            claravid_root,
            tmp_path / "b",
            "data.split.val_missions=[rural_1]",
            "data.split.test_missions=[urban_1]",
        ),
        "did you mean train.steps": tiny(claravid_root, tmp_path / "c", "train.step=3"),
        "multiple of": tiny(
            claravid_root, tmp_path / "d", "train.batch_size=3", "data.crops_per_frame=2"
        ),
        # Checked before the first step, not at the first validation.
        # 75 m blocks balance the fixture's missions: no SplitBalanceWarning line beside it
        # (80 m did while the block grid was anchored at 0; the warning measures 75 now).
        "fewer than val.bins=50": tiny(
            claravid_root, tmp_path / "e", "val.bins=50", "data.split.block_size=75"
        ),
    }
    for message, args in cases.items():
        assert main(["--config", "demo", *args]) == 2, message
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1, err


@pytest.mark.slow
def test_out_dir_rules_and_resume_messages(claravid_root, tmp_path, capsys):
    out = tmp_path / "run"
    args = ["--config", "demo", *tiny(claravid_root, out, "train.steps=2", "val.every=0")]
    assert main([*args, "--resume"]) == 0
    text = capsys.readouterr().out
    assert "no " in text and "starting a new run" in text
    assert f"claravid-eval --checkpoint {out / 'best.pt'}" in text
    assert f"claravid-export --checkpoint {out / 'best.pt'} --output {out / 'best.onnx'}" in text
    assert main([*args, "--resume"]) == 0
    assert "already finished" in capsys.readouterr().out
    assert main(args) == 2  # same config, no --resume
    assert "pass --resume" in capsys.readouterr().err
    assert main([*args, "train.lr=0.5"]) == 2  # another config
    assert "another config (differs in train.lr)" in capsys.readouterr().err
    assert main([*args, "train.lr=0.5", "--resume"]) == 2
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main(["--config", "demo", *tiny(claravid_root, foreign)]) == 2
    assert "not written by this tool" in capsys.readouterr().err


def test_tensorboard_missing_is_a_clear_error(claravid_root, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # as if not installed
    args = tiny(claravid_root, tmp_path / "r", "train.steps=1", "log.tensorboard=true")
    assert main(["--config", "demo", *args]) == 2
    assert "pip install 'claravid-toolkit[tensorboard]'" in capsys.readouterr().err


def test_tensorboard_event_files_hold_the_logged_scalars(claravid_root, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "tb_run"
    args = tiny(claravid_root, out, "train.steps=2", "train.log_every=1", "val.every=2",
                "log.tensorboard=true")  # fmt: skip
    assert main(["--config", "demo", *args]) == 0
    logged = rows(out)
    events = EventAccumulator(str(out / "tb")).Reload()
    tags = set(events.Tags()["scalars"])
    assert {"loss", "lr", "miou", "miou_bins/low", "miou_bins/high"} <= tags
    losses = {e.step: e.value for e in events.Scalars("loss")}
    expected = {r["step"]: r["loss"] for r in logged if "loss" in r}
    assert set(losses) == set(expected) == {1, 2}
    for step, value in expected.items():
        assert losses[step] == pytest.approx(value, rel=1e-6)  # float32 in the event file
    (miou,) = events.Scalars("miou")
    assert miou.step == 2 and miou.value == pytest.approx(logged[-1]["miou"], rel=1e-6)


def test_atomic_checkpoint_write_survives_a_crash_mid_write(trained_v2_copy, monkeypatch):
    out = trained_v2_copy
    before = sha256(out / "last.pt")
    ckpt = read_checkpoint(out / "last.pt")
    model = models.load_checkpoint(out / "last.pt")
    opt = torch.optim.AdamW(model.head.parameters())
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 1.0)

    def crash(obj, f, *args, **kwargs):  # the disk fills up half-way through the file
        f.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", crash)
    with pytest.raises(OSError, match="disk full"):
        save_training_checkpoint(
            out / "last.pt", model, step=3, config=ckpt["config"], optimizer=opt,
            scheduler=sched, scaler=torch.amp.GradScaler("cpu", enabled=False),
            frames_per_step=4, best_miou=None, best_step=None, metrics=None,
            backbone_trained=False,
        )  # fmt: skip
    assert sha256(out / "last.pt") == before  # the old file, whole
    assert sorted(os.listdir(out)) == sorted(  # and no temp file left behind
        ["config.yaml", "metrics.jsonl", "curves.png", "last.pt", "best.pt"]
    )


# The six claravid_syndrone_to_* configs differ only in the real validation set; one trains
# here (tests/train/test_syndrone_configs.py opens the validation set of each).
SHIPPED = [
    n
    for n in shipped_names()
    if n != "augment" and (not n.startswith("claravid_syndrone_to_") or n.endswith("_udd6"))
]


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_config_trains_two_steps(name, claravid_root, uavid_root, tmp_path):
    shipped = cfg = load_config(name, ["model.weights=null"])  # DINOv3's need a weights file
    extra = []
    if models.backbone_spec(cfg.model.backbone).patch_size == 16:  # crops and windows of 32
        extra += ["data.augment.crop_height=32", "data.augment.crop_width=32", "val.window=32"]
    if cfg.data.dataset == "uavid":
        extra += [f"data.root={uavid_root}", "data.val_split=val"]
    if cfg.data.val_dataset == "uavid":
        extra += [f"data.val_root={uavid_root}", "data.val_split=val"]
    if cfg.data.val_dataset in LAYOUT_DATASETS:  # a tiny tree of that real dataset
        make_tree(tmp_path / "real", cfg.data.val_dataset)
        extra += [f"data.val_root={tmp_path / 'real'}", f"data.val_split={cfg.data.val_split}",
                  "val.bins=1"]  # fmt: skip
    extra += HEAD_OVERRIDES[cfg.model.head]  # the tiny widths of the config's own head
    args = tiny(claravid_root, tmp_path / "run", "train.steps=2", "train.batch_size=2",
                "val.every=0", "data.num_workers=0", *extra)  # fmt: skip
    cfg = load_config(name, args)
    result = train(cfg)
    assert result.step == 2 and result.best_step == 2  # the final validation, at step 2
    assert result.best_miou == pytest.approx(miou_by_hand(tmp_path / "run" / "last.pt", cfg))
    assert read_checkpoint(tmp_path / "run" / "last.pt")["config"]["model"]["backbone"] == (
        shipped.model.backbone
    )


def test_class_weights_reach_the_loss(uavid_root, tmp_path):
    """Same seed, weights and first batch: only the class weights differ, so the first step's
    loss must differ (it would not if the weights were computed but never given to the loss)."""
    first = {}
    for weights in ("none", "median_frequency"):
        out = tmp_path / weights
        args = tiny(uavid_root, out, "data.dataset=uavid", "data.val_dataset=uavid",
                    "data.train_split=train", "data.val_split=val", "train.steps=1",
                    f"data.class_weights={weights}", "train.batch_size=2", "train.log_every=1",
                    "val.every=0")  # fmt: skip
        cfg = load_config("demo", args)
        result = train(cfg)
        assert result.step == 1 and result.best_step == 1
        assert result.best_miou == pytest.approx(miou_by_hand(out / "last.pt", cfg))
        first[weights] = rows(out)[0]["loss"]
    assert abs(first["median_frequency"] - first["none"]) > 1e-3 * first["none"], first


def test_the_model_sees_crops_normalised_with_the_config_s_mean_and_std(claravid_root, tmp_path):
    """Crops travel as uint8 and are normalised on the device: undoing the config's
    normalisation on what the model received must give whole pixel values in 0..255 (it does
    not if another mean/std, or none, was applied)."""
    mean, std = (0.1, 0.3, 0.7), (0.5, 0.25, 0.125)
    seen = []

    def first_input(module, args):  # the outermost module of the first step is called first
        if not seen:
            seen.append(args[0].detach().clone())

    handle = torch.nn.modules.module.register_module_forward_pre_hook(first_input)
    try:
        extra = ["train.steps=1", "val.every=0", f"data.augment.mean={list(mean)}",
                 f"data.augment.std={list(std)}"]  # fmt: skip
        cfg = load_config("demo", tiny(claravid_root, tmp_path / "run", *extra))
        with pytest.warns(StatisticsWarning, match=r"not the statistics dinov2_vits14 was pre"):
            train(cfg)
    finally:
        handle.remove()
    (x,) = seen
    assert x.dtype == torch.float32 and x.shape[1:] == (3, 28, 28)
    pixels = (x * torch.tensor(std).view(3, 1, 1) + torch.tensor(mean).view(3, 1, 1)) * 255
    torch.testing.assert_close(pixels, pixels.round(), rtol=0, atol=2e-3)
    assert pixels.min() > -0.01 and pixels.max() < 255.01 and pixels.std() > 1  # not one flat value


def _first_model_input(run):
    """The first tensor a module receives while ``run()`` trains: the outermost call of the
    first step is the model's forward (the crops as normalised on the device)."""
    seen = []

    def first_input(module, args):
        if not seen:
            seen.append(args[0].detach().clone())

    handle = torch.nn.modules.module.register_module_forward_pre_hook(first_input)
    try:
        run()
    finally:
        handle.remove()
    return seen[0]


def _assert_normalised_with(x, mean, std):
    """Undoing ``(pixels / 255 - mean) / std`` gives whole pixel values in 0..255 only for the
    statistics that were applied."""
    pixels = (x * torch.tensor(std).view(3, 1, 1) + torch.tensor(mean).view(3, 1, 1)) * 255
    torch.testing.assert_close(pixels, pixels.round(), rtol=0, atol=2e-3)
    assert pixels.min() > -0.01 and pixels.max() < 255.01 and pixels.std() > 1


SAT493M = ((0.430, 0.411, 0.296), (0.213, 0.156, 0.143))  # DINOv3 SAT's published statistics
IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))


def test_a_sat_backbone_trains_on_sat_statistics_without_naming_them(trained_sat):
    """No data.augment.mean/std in the config (the session's tiny SAT run): a dinov3_*_sat
    backbone's crops reach it normalised with SAT-493M's statistics (not ImageNet's), and the
    checkpoint records them."""
    x = trained_sat["first_input"]
    assert x.dtype == torch.float32 and x.shape[1:] == (3, 32, 32)
    _assert_normalised_with(x, *SAT493M)
    with pytest.raises(AssertionError):  # the check tells the two apart
        _assert_normalised_with(x, *IMAGENET)
    augment = read_checkpoint(trained_sat["ckpt"])["config"]["data"]["augment"]
    assert (tuple(augment["mean"]), tuple(augment["std"])) == SAT493M


def test_statistics_named_against_a_sat_backbone_warn_once_and_are_used(
    claravid_root, tmp_path, capsys
):
    """Named explicitly, other statistics are the ones applied (an experiment may want them),
    with one warning naming both."""
    stats = [f"data.augment.mean={list(IMAGENET[0])}", f"data.augment.std={list(IMAGENET[1])}"]
    args = tiny_v3(claravid_root, tmp_path / "run", "train.steps=1", "val.every=0", *stats,
                   backbone="dinov3_vitl16_sat")  # fmt: skip
    x = _first_model_input(lambda: main(["--config", "demo", *args]))
    _assert_normalised_with(x, *IMAGENET)
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines()
                if line.startswith("claravid-train: warning: data.augment.mean")]  # fmt: skip
    assert len(warnings) == 1, err
    assert "(0.485, 0.456, 0.406)" in warnings[0] and "dinov3_vitl16_sat" in warnings[0]
    assert "mean (0.43, 0.411, 0.296), std (0.213, 0.156, 0.143)" in warnings[0]


@pytest.mark.slow
def test_loader_workers_draw_the_same_batches(claravid_root, tmp_path):
    """Crops are seeded by position, not by worker: 2 workers train the very same weights."""
    states = []
    for workers in (0, 2):
        out = tmp_path / f"w{workers}"
        extra = ["train.steps=3", "val.every=0", f"data.num_workers={workers}"]
        train(load_config("demo", tiny(claravid_root, out, *extra)))
        states.append(read_checkpoint(out / "last.pt")["model"])
    for key, value in states[0].items():
        assert torch.equal(value, states[1][key]), key


def test_complexity_balanced_sampler_trains(claravid_root, tmp_path):
    out = tmp_path / "run"
    extra = ["train.steps=2", "val.every=0", "data.sampler=complexity_balanced"]
    assert train(load_config("demo", tiny(claravid_root, out, *extra))).step == 2
    bad = tiny(claravid_root, tmp_path / "b", *extra, "data.sampler_bins=1000")
    with pytest.raises(ValueError, match="more than the 25 training frames"):  # 150 m blocks
        train(load_config("demo", bad))


@pytest.mark.parametrize("backbone", ["dinov2_vits14_reg", "dinov3_vitl16_sat", "dinov3_vits16"])
def test_end_to_end_training_leaves_no_parameter_without_a_gradient(backbone):
    """``model.freeze_backbone: false``: every trainable parameter gets a gradient (DDP refuses
    one that never does): the pre-training-only mask token and DINOv3 SAT's local_cls_norm are
    frozen."""
    torch.manual_seed(0)
    kwargs = {"embed_dim": 32, "depth": 4, "num_heads": 2}
    model = models.build_model(backbone, 3, backbone_kwargs=kwargs, layers=[0, 1, 2, 3],
                               features=8, out_channels=[8, 8, 8, 8])  # fmt: skip
    model.unfreeze_backbone().train()
    patch = model.patch_size
    model(torch.randn(1, 3, 2 * patch, 3 * patch)).sum().backward()
    missing = [n for n, p in model.named_parameters() if p.requires_grad and p.grad is None]
    assert missing == []
    assert any(n.startswith("backbone.blocks") and p.grad is not None
               for n, p in model.named_parameters())  # fmt: skip


def test_a_crops_padding_is_ignored_by_the_loss_and_the_ignore_id_is_no_setting(claravid_root):
    """A frame smaller than the crop is padded with the one ignore id (255); the training loss is
    the cross-entropy of the frame's own pixels alone, computed here by hand. An
    ``ignore_index`` setting (once accepted: it padded with any id while the loss ignored 255
    only, so padding trained as a class) is refused at every entry."""
    import numpy as np

    from claravid.data.transforms import AugmentConfig, augment_config, train_transforms
    from claravid.train.config import ConfigError
    from claravid.train.loop import segmentation_loss

    rng = np.random.default_rng(0)
    image = rng.integers(1, 256, (3, 20, 24), dtype=np.uint8)  # no 0: the padding is black
    mask = rng.integers(0, 3, (20, 24)).astype(np.uint8)
    still = dict.fromkeys(
        ("hflip_p", "color_jitter_p", "lighting_p", "rotate_p", "distortion_p"), 0
    )
    crop = train_transforms({"crop_height": 28, "crop_width": 42, **still})
    sample = crop({"image": torch.from_numpy(image), "mask": torch.from_numpy(mask)})
    frame = sample["image"].numpy().sum(0) > 0
    top, left = np.argwhere(frame).min(0)
    assert frame.sum() == 20 * 24 and frame[top : top + 20, left : left + 24].all()
    got = sample["mask"].numpy()
    np.testing.assert_array_equal(got[top : top + 20, left : left + 24], mask)
    assert (got[~frame] == 255).all()

    logits = torch.randn(
        1, 3, 28, 42, generator=torch.Generator().manual_seed(1), dtype=torch.float64
    )
    logits[0, :, ~torch.from_numpy(frame)] = 1e4  # whatever is predicted on the padding
    loss = segmentation_loss(logits, torch.from_numpy(got).long()[None])
    z = logits[0].numpy()[:, top : top + 20, left : left + 24]
    log_p = z - np.log(np.exp(z - z.max(0)).sum(0)) - z.max(0)  # log-softmax over classes
    by_hand = -np.take_along_axis(log_p, mask[None].astype(np.int64), 0).mean()
    assert loss.item() == pytest.approx(by_hand, rel=1e-6)

    with pytest.raises(TypeError, match="ignore_index"):
        AugmentConfig(ignore_index=7)
    with pytest.raises(ValueError, match="ignore_index"):
        augment_config({"ignore_index": 7})
    with pytest.raises(
        ConfigError, match=re.escape("unknown config key 'data.augment.ignore_index'")
    ):
        load_config("demo", tiny(claravid_root, "out", "data.augment.ignore_index=7"))

"""Training with each head: the config's choice and its checks, resume, validation per bin, and
the use case of the choice: two heads trained on one split, evaluated and compared paired."""

import json

import pytest
import torch

import claravid.train.loop as loop
from claravid.eval.cli.evaluate import main as eval_main
from claravid.models.checkpoint import read_checkpoint
from claravid.train import TrainingDiverged, load_config, train
from claravid.train.cli import main as train_main
from claravid.train.config import ConfigError, changed_keys
from tests.tiny import HEAD_OVERRIDES, tiny_v3
from tests.train.test_resume import assert_same_state, training_rows


def _one_line(capsys, *words):
    lines = capsys.readouterr().err.strip().splitlines()
    err = [line for line in lines if "warning: " not in line]
    assert len(err) == 1 and err[0].startswith("claravid-train: error: "), lines
    for word in words:
        assert word in err[0], err[0]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["model.head=fcn"], "bad value for model.head: 'fcn' (one of dpt, linear, upernet)"),
        (["model.head=linear", "model.layers=null", "model.out_channels=null"],
         "model.features is not a setting of the linear head (it takes model.layers, "
         "model.use_cls; features belongs to dpt, upernet)"),
        (["model.head=upernet"], "model.out_channels is not a setting of the upernet head"),
        (["model.head=upernet", "model.out_channels=null", "model.use_cls=true"],
         "model.use_cls is not a setting of the upernet head (it takes model.layers, "
         "model.features; use_cls belongs to dpt, linear)"),
        (["model.head=upernet", "model.out_channels=null", "model.layers=[1,2,3]"],
         "model.layers needs 4 block indices for the upernet head, got [1, 2, 3]"),
    ],
)  # fmt: skip
def test_a_head_or_setting_that_does_not_exist_is_one_line_exit_2(
    overrides, message, claravid_root, tmp_path, capsys
):
    args = tiny_v3(claravid_root, tmp_path / "run", *overrides)
    with pytest.raises(ConfigError) as info:
        load_config("demo", args)
    assert message in str(info.value)
    assert train_main(["--config", "demo", *args]) == 2
    _one_line(capsys, message)
    assert not (tmp_path / "run").exists()


def test_upernet_refuses_one_crop_per_forward_pass_before_training(claravid_root, tmp_path, capsys):
    args = tiny_v3(claravid_root, tmp_path / "run", *HEAD_OVERRIDES["upernet"], "train.steps=1",
                   "train.batch_size=2", "train.grad_accum=2")  # fmt: skip
    assert train_main(["--config", "demo", *args]) == 2
    _one_line(capsys, "model.head=upernet", "at least 2 crops per forward pass", "gives 1")
    assert not (tmp_path / "run" / "last.pt").exists()


@pytest.mark.parametrize(
    ("name", "head", "optimiser"),
    [
        ("claravid_linear_dinov3_vitl16", "linear",
         {"lr": 1e-3, "weight_decay": 1e-3, "warmup_steps": 1500, "schedule": "cosine",
          "grad_clip": 0.0}),
        ("claravid_linear_dinov3_vitl16_sat", "linear",
         {"lr": 1e-3, "weight_decay": 1e-3, "warmup_steps": 1500, "schedule": "cosine",
          "grad_clip": 0.0}),
        ("claravid_upernet_dinov3_vitl16", "upernet",
         {"lr": 6e-5, "weight_decay": 0.01, "warmup_steps": 1500, "poly_power": 1.0,
          "grad_clip": 0.0}),
        ("claravid_upernet_dinov3_vitl16_sat", "upernet",
         {"lr": 6e-5, "weight_decay": 0.01, "warmup_steps": 1500, "poly_power": 1.0,
          "grad_clip": 0.0}),
    ],
)  # fmt: skip
def test_head_configs_differ_from_the_dpt_protocol_by_head_and_optimiser(name, head, optimiser):
    """The same data, backbone, crops and windows as the DPT config of the same backbone: only
    the head and the official protocol's optimiser settings differ."""
    weights = ["model.weights=/w.pth"]
    cfg = load_config(name, weights)
    dpt = load_config(name.replace(f"_{head}_", "_dpt_"), weights)
    assert cfg.model.head == head and dpt.model.head == "dpt"
    assert {key: cfg.train[key] for key in optimiser} == pytest.approx(optimiser)
    own = [f"train.{key}" for key, value in optimiser.items() if dpt.train[key] != value]
    assert changed_keys(dpt, cfg) == sorted(["model.head", *own])
    assert len(own) >= 4  # lr, warmup and clipping at least


STOP = ("train.steps=6", "train.checkpoint_every=2", "val.every=0", "train.log_every=1",
        "train.lr=3e-3")  # fmt: skip


@pytest.mark.parametrize("head", ["linear", "upernet"])
def test_resume_is_bit_for_bit_and_validation_is_per_bin(
    head, claravid_root, tmp_path, monkeypatch
):
    """A run stopped at step 5 (an injected inf loss; last.pt holds step 4) and resumed ends
    where the uninterrupted run ends: the heads' BatchNorm statistics travel in checkpoints."""

    def overrides(out):
        return tiny_v3(claravid_root, out, *HEAD_OVERRIDES[head], *STOP)

    reference = train(load_config("demo", overrides(tmp_path / "reference")))
    assert list(reference.last_val["miou_bins"]) == ["low", "medium", "high"]
    last = read_checkpoint(tmp_path / "reference" / "last.pt")
    assert last["model_args"]["head"] == head
    # The BatchNorm statistics were trained: not their init any more.
    running = [v for k, v in last["model"].items() if k.endswith("running_mean")]
    assert running and all(v.abs().sum() > 0 for v in running)

    out = tmp_path / "stopped"
    real, calls = loop.F.cross_entropy, []

    def poisoned(*args, **kwargs):
        calls.append(1)
        loss = real(*args, **kwargs)
        return loss * float("inf") if len(calls) == 5 else loss

    with monkeypatch.context() as patch:
        patch.setattr(loop.F, "cross_entropy", poisoned)
        with pytest.raises(TrainingDiverged, match="at step 5"):
            train(load_config("demo", overrides(out)))
    assert train(load_config("demo", overrides(out)), resume=True).step == 6
    assert_same_state(read_checkpoint(out / "last.pt"), last)
    assert training_rows(out) == training_rows(tmp_path / "reference")


@pytest.mark.slow
def test_two_heads_on_one_split_compare_paired_per_bin(claravid_root, tmp_path, capsys):
    """The linear protocol and UperNet on the same tiny DINOv3 backbone and split, each
    evaluated from its checkpoint alone, then compared image by image."""
    reports = {}
    for head in ("linear", "upernet"):
        args = tiny_v3(claravid_root, tmp_path / head, *HEAD_OVERRIDES[head], "train.steps=3",
                       "model.freeze_backbone=true",
                       "val.every=0")  # fmt: skip
        train(load_config("demo", args))
        out = tmp_path / f"report_{head}"
        argv = ["--checkpoint", str(tmp_path / head / "last.pt"), "--split", "test", "--bins",
                "2", "--hardest", "0", "--bootstrap", "100", "--output", str(out),
                "--no-progress"]  # fmt: skip
        assert eval_main(argv) == 0
        reports[head] = json.loads((out / "report.json").read_text())
    a, b = reports["linear"], reports["upernet"]
    assert [i["path"] for i in a["images"]] == [i["path"] for i in b["images"]]
    assert a["overall"]["miou"] != b["overall"]["miou"]  # two different models
    argv = ["compare", str(tmp_path / "report_linear" / "report.json"),
            str(tmp_path / "report_upernet" / "report.json"), "--bootstrap", "100",
            "--output", str(tmp_path / "cmp")]  # fmt: skip
    assert eval_main(argv) == 0
    (entry,) = json.loads((tmp_path / "cmp" / "compare.json").read_text())["comparisons"]
    assert entry["paired"] is True
    assert entry["overall"]["gap"] == pytest.approx(b["overall"]["miou"] - a["overall"]["miou"])
    for row, bin_a, bin_b in zip(entry["bins"], a["bins"], b["bins"], strict=True):
        assert row["paired"] is True
        assert row["gap"] == pytest.approx(bin_b["miou"] - bin_a["miou"], abs=1e-9)
    assert "compare.md" in capsys.readouterr().out
    assert torch.equal(  # both read the same frozen random backbone (same seed)
        read_checkpoint(tmp_path / "linear" / "last.pt")["model"]["backbone.cls_token"],
        read_checkpoint(tmp_path / "upernet" / "last.pt")["model"]["backbone.cls_token"],
    )

"""``train.amp``: one precision setting (auto | bf16 | fp16 | off), bf16 and fp16 on the CPU too."""

import json

import pytest
import torch

from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config, train
from claravid.train.cli import main
from claravid.train.loop import amp_dtype
from tests.train.conftest import tiny

STEPS = ("train.steps=8", "train.lr=3e-3", "train.log_every=1", "val.every=0")


def losses(out):
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    return [r["loss"] for r in rows if "loss" in r]


def test_what_each_setting_means_on_the_cpu():
    cpu = torch.device("cpu")
    assert amp_dtype("auto", cpu) is None  # float32: the CPU default stays as it was
    assert amp_dtype("off", cpu) is None
    assert amp_dtype("bf16", cpu) is torch.bfloat16
    assert amp_dtype("fp16", cpu) is torch.float16


@pytest.fixture(scope="module")
def untrained_losses(claravid_root, tmp_path_factory):
    """float32 losses of the initial weights on the very batches the runs below draw (the
    batches depend on the seed and the step only; an lr of 1e-12 leaves the weights as they
    are)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("untrained") / "run"
    try:
        train(load_config("demo", tiny(claravid_root, out, *STEPS, "train.lr=1e-12",
                                       "train.amp=off")))  # fmt: skip
    finally:
        torch.set_num_threads(before)
    return losses(out)


@pytest.mark.parametrize("amp", ["bf16", "fp16"])
def test_low_precision_training_on_the_cpu(claravid_root, tmp_path, untrained_losses, amp):
    out = tmp_path / amp
    result = train(load_config("demo", tiny(claravid_root, out, *STEPS, f"train.amp={amp}")))
    assert result.step == 8 and result.best_miou is not None  # validated at that precision too
    got = losses(out)
    assert len(got) == 8 and all(torch.isfinite(torch.tensor(got)))
    # Step 1, same weights and batch: autocast changes the loss a little, not a lot.
    assert got[0] != untrained_losses[0] and got[0] == pytest.approx(untrained_losses[0], rel=0.01)
    # It learns: on each of the last three batches the loss is below the initial weights'.
    assert all(a < b for a, b in zip(got[-3:], untrained_losses[-3:], strict=True)), (
        got,
        untrained_losses,
    )
    ckpt = read_checkpoint(out / "last.pt")
    assert ckpt["config"]["train"]["amp"] == amp
    if amp == "fp16":  # fp16 needs loss scaling: the CPU GradScaler's state is saved
        assert ckpt["scaler"]["scale"] > 0
    else:  # bf16 has float32's range: no scaler
        assert ckpt["scaler"] == {}


def test_off_is_off_although_yaml_reads_it_as_false(claravid_root, tmp_path):
    base = tiny(claravid_root, tmp_path / "r")
    assert load_config("demo", [*base, "train.amp=off"]).train.amp == "off"
    yaml = tmp_path / "off.yaml"
    yaml.write_text("train:\n  amp: off\n")
    assert load_config(yaml, base).train.amp == "off"


@pytest.mark.parametrize("value", ["fp8", "float16", "1", "true"])  # a boolean names none
def test_bad_amp_value_is_one_line_exit_2(claravid_root, tmp_path, capsys, value):
    args = tiny(claravid_root, tmp_path / "r", f"train.amp={value}")
    assert main(["--config", "demo", *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "train.amp" in err and "auto, bf16, fp16, off" in err

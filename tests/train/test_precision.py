"""``train.precision``: the precision names of every command (auto | fp32 | bf16 | fp16), bf16
and fp16 on the CPU too."""

import json

import pytest
import torch

from claravid.infra.precision import autocast_dtype
from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config, train
from claravid.train.cli import main
from tests.tiny import tiny

STEPS = ("train.steps=8", "train.lr=3e-3", "train.log_every=1", "val.every=0")


def losses(out):
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    return [r["loss"] for r in rows if "loss" in r]


def test_what_each_setting_means_on_the_cpu():
    cpu = torch.device("cpu")
    assert autocast_dtype("auto", cpu) is None  # float32: the CPU default stays as it was
    assert autocast_dtype("fp32", cpu) is None
    assert autocast_dtype("bf16", cpu) is torch.bfloat16
    assert autocast_dtype("fp16", cpu) is torch.float16


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
                                       "train.precision=fp32")))  # fmt: skip
    finally:
        torch.set_num_threads(before)
    return losses(out)


@pytest.mark.parametrize("precision", ["bf16", "fp16"])
def test_low_precision_training_on_the_cpu(claravid_root, tmp_path, untrained_losses, precision):
    out = tmp_path / precision
    args = tiny(claravid_root, out, *STEPS, f"train.precision={precision}")
    result = train(load_config("demo", args))
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
    assert ckpt["config"]["train"]["precision"] == precision
    if precision == "fp16":  # fp16 needs loss scaling: the CPU GradScaler's state is saved
        assert ckpt["scaler"]["scale"] > 0
    else:  # bf16 has float32's range: no scaler
        assert ckpt["scaler"] == {}


def test_the_flag_is_the_config_key(claravid_root, tmp_path):
    """``claravid-train --precision P`` is ``train.precision=P``, as ``--precision`` of
    claravid-eval and claravid-predict takes the same names."""
    from claravid.train.cli import build_parser, overrides

    base = tiny(claravid_root, tmp_path / "r")
    args = build_parser().parse_args(["--config", "demo", "--precision", "bf16", *base])
    assert load_config("demo", overrides(args)).train.precision == "bf16"
    assert load_config("demo", base).train.precision == "auto"  # the shipped configs say auto


@pytest.mark.parametrize(
    ("value", "shown"),
    [("fp8", "'fp8'"), ("float16", "'float16'"), ("1", "'1'"),
     ("off", "'False' (one of auto, fp32, bf16, fp16 (YAML read a boolean))"),
     ("true", "'True' (one of auto, fp32, bf16, fp16 (YAML read a boolean))")],
)  # fmt: skip
def test_bad_precision_is_one_line_exit_2(claravid_root, tmp_path, capsys, value, shown):
    args = tiny(claravid_root, tmp_path / "r", f"train.precision={value}")
    assert main(["--config", "demo", *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"bad value for train.precision: {shown}" in err and "one of auto, fp32" in err
    with pytest.raises(SystemExit) as info:  # the flag: argparse's check, the same everywhere
        main(["--config", "demo", "--precision", value, *tiny(claravid_root, tmp_path / "r")])
    assert info.value.code == 2
    assert "argument --precision: invalid choice" in capsys.readouterr().err

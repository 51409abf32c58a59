"""DDP on CPU: 2 gloo processes train what 1 process trains with the same global batch.

Step semantics (``claravid.train.loop``): the loss of a step is the mean of its micro-batch losses,
and rank r of W takes micro-batch r of each step. So 2 ranks × 1 micro-batch of 2 frames equals 1
process × 2 micro-batches of 2 frames: same frames, same crops, same mean gradient. With 2 ranks the
weights are even bit for bit the same: DDP computes (g0 + g1) / 2 where one process accumulates
g0 / 2 + g1 / 2, and halving is exact in floating point. (With 3 ranks they would agree to
rounding only;
one process with one micro-batch of 4 frames differs by ~6e-7 after 8 steps: the pixel mean over 4
crops is not summed in the same order.) With accumulation on each rank (2 ranks × 2 micro-batches vs
1 × 4) the sums are grouped differently: equal to float rounding, which is what the second case
checks (and that ``no_sync`` still all-reduces)."""

import os
import subprocess

import pytest
import torch

from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config, train
from claravid.train.logs import read_metrics
from tests.helpers.torchrun import torchrun
from tests.tiny import tiny

EXTRA = ("train.steps=8", "train.checkpoint_every=4", "val.every=4", "train.log_every=1")


def same(a, b, exact):
    return a == b if exact else a == pytest.approx(b, rel=1e-5, abs=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize(("accum", "exact"), [(1, True), (2, False)])
def test_two_gloo_ranks_match_one_process_with_the_same_global_batch(
    claravid_root, tmp_path, accum, exact
):
    batch = f"train.batch_size={4 * accum}"
    single = tmp_path / "single"
    extra = (*EXTRA, batch, f"train.grad_accum={2 * accum}")
    train(load_config("demo", tiny(claravid_root, single, *extra)))

    ddp = tmp_path / "ddp"
    run = subprocess.run(
        [*torchrun(2), "-m", "claravid.train", "--config", "demo",
         *tiny(claravid_root, ddp, *EXTRA, batch, f"train.grad_accum={accum}")],
        capture_output=True, text=True, timeout=300,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-4000:]
    assert run.stdout.count("results in") == 1  # rank 0 alone reports

    a, b = read_checkpoint(single / "last.pt"), read_checkpoint(ddp / "last.pt")
    assert a["step"] == b["step"] == 8 and a["sampler"] == b["sampler"]
    for key, value in a["model"].items():
        if exact:
            assert torch.equal(b["model"][key], value), key
        else:
            torch.testing.assert_close(b["model"][key], value, rtol=1e-4, atol=1e-5, msg=key)
    rows_a, rows_b = read_metrics(single / "metrics.jsonl"), read_metrics(ddp / "metrics.jsonl")
    assert [r["step"] for r in rows_a] == [r["step"] for r in rows_b]  # rank 0 wrote each row once
    for ra, rb in zip(rows_a, rows_b, strict=True):
        for key in ("loss", "miou"):
            if key in ra:
                assert same(rb[key], ra[key], exact), (ra["step"], key)
    losses = [r["loss"] for r in rows_a if "loss" in r]
    assert len(set(losses)) == len(losses) == 8  # the weights moved at every step

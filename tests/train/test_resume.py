"""Resume after ``kill -9`` ends bit for bit where the uninterrupted run ends (CPU, fixed seed)."""

import math
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from claravid.models.checkpoint import read_checkpoint
from claravid.train import TrainingDiverged, load_config, train
from claravid.train.logs import read_metrics
from tests.helpers.files import sha256
from tests.tiny import tiny, tiny_v3

STEPS = 24
EXTRA = (f"train.steps={STEPS}", "train.checkpoint_every=3", "val.every=8", "train.log_every=1",
         "train.warmup_steps=5")  # fmt: skip


def command(root, out, *flags):
    return [
        sys.executable,
        "-m",
        "claravid.train",
        "--config",
        "demo",
        *tiny(root, out, *EXTRA),
        *flags,
    ]


def env():
    # One thread, as the in-process reference run (the conftest fixture): same kernels, same bits.
    return {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


def checkpoint_step(path):
    try:
        return read_checkpoint(path)["step"]
    except Exception:  # not written yet
        return -1


def assert_same_state(a, b):
    assert a["step"] == b["step"]
    assert a["model"].keys() == b["model"].keys()
    for key in a["model"]:
        assert torch.equal(a["model"][key], b["model"][key]), key
    for pid, state in a["optimizer"]["state"].items():
        for name, value in state.items():
            assert torch.equal(value, b["optimizer"]["state"][pid][name]), (pid, name)
    assert a["scheduler"] == b["scheduler"]
    assert torch.equal(a["rng"]["torch"], b["rng"]["torch"])
    assert a["sampler"] == b["sampler"]
    assert (a["best_miou"], a["best_step"]) == (b["best_miou"], b["best_step"])


def training_rows(out):
    return [
        {k: v for k, v in r.items() if k != "images_per_s"}
        for r in read_metrics(out / "metrics.jsonl")
    ]


@pytest.mark.slow
def test_resume_after_sigkill_is_bit_for_bit(claravid_root, tmp_path):
    reference = tmp_path / "reference"
    train(load_config("demo", tiny(claravid_root, reference, *EXTRA)))

    out = tmp_path / "killed"
    proc = subprocess.Popen(command(claravid_root, out), env=env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)  # fmt: skip
    deadline = time.monotonic() + 120
    while checkpoint_step(out / "last.pt") < 9 and proc.poll() is None:
        assert time.monotonic() < deadline, "the run made no progress"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL, proc.stderr.read().decode()[-2000:]
    killed_at = checkpoint_step(out / "last.pt")
    assert 9 <= killed_at < STEPS  # after a validation (step 8), before the end

    run = subprocess.run(command(claravid_root, out, "--resume"), env=env(),
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    assert f"resuming {out / 'last.pt'} at step {killed_at}/{STEPS}" in run.stdout

    assert_same_state(read_checkpoint(out / "last.pt"), read_checkpoint(reference / "last.pt"))
    assert_same_state(read_checkpoint(out / "best.pt"), read_checkpoint(reference / "best.pt"))
    # metrics.jsonl reads as one run: no row twice, same losses and validation scores.
    assert training_rows(out) == training_rows(reference)


FAST = ("train.steps=8", "train.checkpoint_every=4", "val.every=0", "train.log_every=1",
        "train.lr=3e-3")  # fmt: skip


@pytest.mark.parametrize(
    ("precision", "backbone"),
    [("fp32", "dinov2_vits14"), ("bf16", "dinov2_vits14"), ("fp32", "dinov3_vitl16_sat")],
)
def test_resume_after_a_stop_is_bit_for_bit(
    claravid_root, tmp_path, monkeypatch, precision, backbone
):
    """The fast check of the default run (the SIGKILL test above is slow): a run stopped at
    step 5 (an injected inf loss; last.pt holds step 4) and resumed ends where the
    uninterrupted run ends, in float32 and in bf16 autocast on the CPU alike, with a DINOv2 or
    a DINOv3 backbone (RoPE, storage tokens, the SAT model's unused local_cls_norm)."""
    import claravid.train.loop as loop

    def overrides(out):
        if backbone.startswith("dinov3"):
            return tiny_v3(
                claravid_root, out, *FAST, f"train.precision={precision}", backbone=backbone
            )
        return tiny(claravid_root, out, *FAST, f"train.precision={precision}")

    reference = tmp_path / "reference"
    train(load_config("demo", overrides(reference)))

    out = tmp_path / "stopped"
    cfg = load_config("demo", overrides(out))
    real, calls = loop.F.cross_entropy, []

    def poisoned(*args, **kwargs):  # torch's loss, made infinite at the 5th step
        calls.append(1)
        loss = real(*args, **kwargs)
        return loss * float("inf") if len(calls) == 5 else loss

    with monkeypatch.context() as patch:
        patch.setattr(loop.F, "cross_entropy", poisoned)
        with pytest.raises(TrainingDiverged, match="at step 5"):
            train(cfg)
    assert read_checkpoint(out / "last.pt")["step"] == 4
    result = train(load_config("demo", overrides(out)), resume=True)
    assert result.step == 8
    assert_same_state(read_checkpoint(out / "last.pt"), read_checkpoint(reference / "last.pt"))
    assert training_rows(out) == training_rows(reference)
    losses = [r["loss"] for r in training_rows(reference) if "loss" in r]
    assert len(losses) == 8 and all(math.isfinite(x) for x in losses)


BEST = ("train.steps=8", "train.checkpoint_every=2", "val.every=2", "train.log_every=1",
        "train.lr=1e-2")  # fmt: skip


def test_a_resumed_run_keeps_the_best_of_before_the_interruption(
    claravid_root, tmp_path, monkeypatch
):
    """Validated at steps 2 and 4, stopped at step 5 (an injected inf loss), resumed with its
    val frames moved (``data.val_root``, a change a resume accepts) to a copy whose labels are
    one class everywhere: every validation after the resume scores below the best before it,
    which ``best.pt`` must keep, with its step, as must the run's own record of it."""
    import claravid.train.loop as loop
    from claravid.io import modalities
    from claravid.train.data import build_val_dataset

    out = tmp_path / "run"
    cfg = load_config("demo", tiny(claravid_root, out, *BEST))
    real, calls = loop.F.cross_entropy, []

    def poisoned(*args, **kwargs):  # torch's loss, made infinite at the 5th step
        calls.append(1)
        loss = real(*args, **kwargs)
        return loss * float("inf") if len(calls) == 5 else loss

    with monkeypatch.context() as patch:
        patch.setattr(loop.F, "cross_entropy", poisoned)
        with pytest.raises(TrainingDiverged, match="at step 5"):
            train(cfg)
    before = {r["step"]: r["miou"] for r in read_metrics(out / "metrics.jsonl") if "miou" in r}
    assert sorted(before) == [2, 4] and max(before.values()) > 0
    best_step = max(before, key=lambda s: (before[s], -s))  # the first of equal scores
    best_digest = sha256(out / "best.pt")

    moved = tmp_path / "moved"
    shutil.copytree(claravid_root, moved)
    resumed_cfg = load_config("demo", tiny(claravid_root, out, *BEST, f"data.val_root={moved}"))
    for frame in build_val_dataset(resumed_cfg).frames:
        pan = frame.paths["pan_seg"]
        shape = modalities.read_semantic(pan).shape
        modalities.write_pan_seg(pan, np.full(shape, 16, np.uint8), np.zeros(shape, np.int64))
    result = train(resumed_cfg, resume=True)

    after = {r["step"]: r["miou"] for r in read_metrics(out / "metrics.jsonl") if "miou" in r}
    assert sorted(after) == [2, 4, 6, 8] and {s: after[s] for s in (2, 4)} == before
    assert max(after[6], after[8]) < before[best_step]  # the precondition: worse after resume
    assert sha256(out / "best.pt") == best_digest
    best = read_checkpoint(out / "best.pt")
    assert (best["step"], best["best_step"], best["best_miou"]) == (
        best_step, best_step, before[best_step]
    )  # fmt: skip
    last = read_checkpoint(out / "last.pt")
    assert (last["step"], last["best_step"], last["best_miou"]) == (8, best_step, before[best_step])
    assert (result.best_step, result.best_miou) == (best_step, before[best_step])

"""Two nodes on loopback: ``torchrun --nnodes 2 --node_rank 0|1`` (one process each, gloo, c10d
rendezvous on 127.0.0.1) trains the weights and writes the report that one process does.

This is what a Slurm job does across machines (README, "Beyond one machine"), with both "nodes"
on this machine: node 0 hosts the rendezvous store (``is_host=1``), node 1 joins it. Training:
2 ranks × 1 micro-batch equal 1 process × 2 micro-batches of the same global batch bit for bit
(see tests/train/test_ddp.py for why); evaluation: the ranks' per-image confusions are gathered
in dataset order, so the report is the one-process report.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.cli.evaluate import main as eval_main
from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config, train
from claravid.train.logs import read_metrics
from tests.helpers.torchrun import free_port
from tests.tiny import tiny

# data.val_split=val: the tiny tree's val split holds an odd count of frames (5 of 36), so the
# two ranks get uneven shards.
EXTRA = ("train.steps=4", "train.checkpoint_every=4", "val.every=0", "train.log_every=1",
         "train.batch_size=4", "data.val_split=val")  # fmt: skip


def node(rank: int, port: int) -> list[str]:
    """``torchrun`` for node ``rank`` of 2 (one process), rendezvousing on 127.0.0.1:port."""
    return [
        sys.executable, "-m", "torch.distributed.run", "--nnodes=2", f"--node_rank={rank}",
        "--nproc_per_node=1", "--rdzv-backend=c10d", f"--rdzv-endpoint=127.0.0.1:{port}",
        f"--rdzv-conf=is_host={int(rank == 0)}", "--local-addr=127.0.0.1",
    ]  # fmt: skip


def two_nodes(args: list[str], logs, timeout: int = 300) -> None:
    """Start both nodes at once and wait; each node's output goes to ``logs/node<r>.txt``."""
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = []
    for rank in (0, 1):
        with open(logs / f"node{rank}.txt", "w") as log:
            procs.append(subprocess.Popen([*node(rank, port), *args], stdout=log,
                                          stderr=subprocess.STDOUT, env=env))  # fmt: skip
    try:
        codes = [p.wait(timeout=timeout) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    text = "\n".join((logs / f"node{r}.txt").read_text()[-3000:] for r in (0, 1))
    assert codes == [0, 0], text


def without_source(report):
    return {k: v for k, v in report.items() if k != "source"}


@pytest.mark.slow
def test_two_nodes_train_and_evaluate_as_one_process(claravid_root, tmp_path):
    single = tmp_path / "single"
    train(load_config("demo", tiny(claravid_root, single, *EXTRA, "train.grad_accum=2")))
    multi = tmp_path / "multi"
    two_nodes(["-m", "claravid.train", "--config", "demo",
               *tiny(claravid_root, multi, *EXTRA, "train.grad_accum=1")], tmp_path)  # fmt: skip
    a, b = read_checkpoint(single / "last.pt"), read_checkpoint(multi / "last.pt")
    assert a["step"] == b["step"] == 4 and a["sampler"] == b["sampler"]
    for key, value in a["model"].items():
        assert torch.equal(b["model"][key], value), key
    rows_a, rows_b = read_metrics(single / "metrics.jsonl"), read_metrics(multi / "metrics.jsonl")
    assert [r.get("loss") for r in rows_a] == [r.get("loss") for r in rows_b]
    assert rows_a[-1]["miou"] == rows_b[-1]["miou"]  # the final validation, sharded over 2 ranks

    # Evaluate the trained checkpoint (its config names the data, palette, split and windows).
    argv = ["-m", "claravid.eval", "--checkpoint", str(single / "last.pt"), "--bins", "2",
            "--no-progress", "--device", "cpu"]  # fmt: skip
    two_nodes([*argv, "--output", str(tmp_path / "two")], tmp_path)
    assert eval_main([*argv[2:], "--output", str(tmp_path / "one")]) == 0
    two = json.loads((tmp_path / "two" / "report.json").read_text())
    one = json.loads((tmp_path / "one" / "report.json").read_text())
    # The validation split the checkpoint recorded: an odd count, so the ranks' shards differ.
    expected = len(ClaraVidSegmentation(claravid_root, split="val"))
    assert len(one["images"]) == expected and expected % 2 == 1
    assert without_source(two) == without_source(one)
    with (
        np.load(tmp_path / "two" / "confusions.npz") as x,
        np.load(tmp_path / "one" / "confusions.npz") as y,
    ):
        np.testing.assert_array_equal(x["confusions"], y["confusions"])
        assert x["paths"].tolist() == y["paths"].tolist()

"""Sharding and ordered gathering across 2 real gloo processes."""

import subprocess
import textwrap

import pytest

from claravid.infra.distributed import gather_in_order, shard_indices
from tests.helpers.torchrun import torchrun

SCRIPT = textwrap.dedent(
    """
    import argparse, sys
    from pathlib import Path
    import torch.distributed as dist
    from claravid.infra.cli import run_cli
    from claravid.infra.distributed import init_distributed, shard_indices, gather_in_order

    def run(args):
        info = init_distributed("cpu")
        mine = shard_indices(7)
        out = gather_in_order([f"item{i}" for i in mine], mine)
        line = f"rank{info.rank}/{info.world_size} {mine} {','.join(out)}"
        Path(args.folder, f"rank{info.rank}.txt").write_text(line)
        return 0

    parser = argparse.ArgumentParser()
    parser.add_argument("folder")
    code = run_cli("probe", run, parser)
    # A console script leaves no process group to interpreter shutdown.
    assert not dist.is_initialized(), "the group outlived the command"
    raise SystemExit(code)
    """
)


def test_single_process_is_the_identity():
    assert shard_indices(5) == [0, 1, 2, 3, 4]
    assert shard_indices(5, rank=1, world_size=2) == [1, 3]
    assert gather_in_order(["b", "a"], [1, 0]) == ["a", "b"]
    with pytest.raises(ValueError, match="2 items for 1 indices"):
        gather_in_order(["a", "b"], [0])


@pytest.mark.slow
def test_two_gloo_ranks_gather_everything_in_order(tmp_path):
    script = tmp_path / "probe.py"
    script.write_text(SCRIPT)
    run = subprocess.run(
        [*torchrun(2), str(script), str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    lines = [(tmp_path / f"rank{r}.txt").read_text() for r in (0, 1)]
    everything = ",".join(f"item{i}" for i in range(7))
    assert lines == [
        f"rank0/2 [0, 2, 4, 6] {everything}",
        f"rank1/2 [1, 3, 5] {everything}",
    ]

"""Shards of a file list for job arrays (Slurm): ``--shard k/n`` takes every n-th item from k."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


def parse_shard(text: str) -> tuple[int, int]:
    """``"k/n"`` -> (k, n) with 0 <= k < n; a ValueError says the expected form otherwise.

    An empty text is an error too, never "no shard": ``--shard $SLURM_ARRAY_TASK_ID`` with the
    variable unset must not make one task of a job array do every task's work.
    """
    if not text.strip():
        raise ValueError(
            f"shard must look like k/n (e.g. 0/8), got {text!r}: is the variable that should "
            "give it set?"
        )
    try:
        k_text, n_text = text.split("/")
        k, n = int(k_text), int(n_text)
    except ValueError:
        raise ValueError(f"shard must look like k/n (e.g. 0/8), got {text!r}") from None
    if n < 1 or not 0 <= k < n:
        raise ValueError(
            f"shard {text!r} is out of range: need n >= 1 and 0 <= k < n "
            "(k is 0-based; with SLURM use $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)"
        )
    return k, n


def select_shard(paths: Sequence[Path], k: int, n: int) -> list[Path]:
    """Every n-th path from the k-th: shards balance even when file sizes drift along the list."""
    return list(paths[k::n])

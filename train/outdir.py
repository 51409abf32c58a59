"""The run folder: what may be written where, and what ``--resume`` continues.

``out_dir/config.yaml`` (the resolved config) marks a folder as a training run. Without
``--resume`` a folder holding a run is refused (so a finished run is never overwritten); with
``--resume`` the run continues from ``last.pt`` if its config matches (``out_dir`` itself may
differ: a run folder can be moved or copied), or starts fresh when there is no ``last.pt`` yet
(``make demo`` can always be re-run). A run that stopped before its first step binds the folder
to nothing: the next run may use it with any config.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from claravid.infra.cli import UsageError
from claravid.infra.files import atomic_write_text, check_output_dir
from claravid.train import config as C
from claravid.train.checkpoint import load_training_checkpoint
from claravid.train.logs import read_metrics

MARKER = "config.yaml"


def prepare_out_dir(
    out: Path,
    cfg: DictConfig,
    resume: bool,
    *,
    say: Callable[[str], Any] = print,
) -> dict[str, Any] | None:
    """Check ``out`` for this run, write ``config.yaml``; the checkpoint to resume, or None.

    Raises:
        UsageError: a foreign folder, a run of another config, a run without ``--resume``.
    """
    check_output_dir(out, marker=MARKER, what="out_dir", overwrite=None)  # no --overwrite
    last = out / "last.pt"
    saved = out / MARKER
    ckpt = None
    if saved.is_file() and not last.is_file() and not started(out):
        # A run that stopped before its first step (a bad value, no GPU) left only its config:
        # it binds the folder to nothing.
        say(f"{out} holds no training step of an earlier run: starting a new run there")
        resume = False
        saved.unlink()
    if resume and last.is_file():
        ckpt = load_training_checkpoint(last)
        differ = C.changed_keys(C.from_plain(ckpt["config"]), cfg)
        if differ:
            raise UsageError(
                f"out_dir {out} holds a run of another config (differs in "
                f"{', '.join(differ[:6])}); resume it with its own settings, or choose a new "
                "out_dir=..."
            )
    elif resume:
        say(f"no {last} to resume: starting a new run in {out}")
    elif saved.is_file():
        previous = _load(saved)
        differ = C.changed_keys(previous, cfg) if previous is not None else ["an unreadable file"]
        what = (
            "this config" if not differ else f"another config (differs in {', '.join(differ[:6])})"
        )
        raise UsageError(
            f"out_dir {out} already holds a run of {what}; pass --resume to continue it, "
            "or choose a new out_dir=... (or delete the folder)"
        )
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(saved, C.to_yaml(cfg))
    return ckpt


def started(out: Path) -> bool:
    """Whether a run in ``out`` did any step: a checkpoint or a logged row."""
    has_rows = bool(read_metrics(out / "metrics.jsonl"))
    return has_rows or (out / "last.pt").is_file() or (out / "best.pt").is_file()


def _load(path: Path) -> DictConfig | None:
    """A run's saved config, or None when it no longer parses (an older schema)."""
    try:
        loaded = OmegaConf.load(path)
        if not isinstance(loaded, DictConfig):  # a list: no config of ours
            return None
        return C.from_plain(C.to_plain(loaded, resolve=False))
    except Exception:
        return None

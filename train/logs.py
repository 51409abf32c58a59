"""What a run leaves to read: ``metrics.jsonl``, optional TensorBoard events, the curves PNG.

``metrics.jsonl`` holds one JSON object per line: training rows ``{"step", "loss", "lr",
"images_per_s", "grad_norm"}`` every ``train.log_every`` steps, and validation rows ``{"step",
"miou", "pixel_acc", "per_class_iou", "miou_bins", "boundary_miou", "boundary_miou_bins"}``
(mBoundaryIoU overall and per delentropy bin beside mIoU). A resumed run first drops the rows
written after its checkpoint, so the file reads as if the run had never stopped.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure

from claravid.infra.cli import UsageError
from claravid.infra.files import atomic_save, atomic_write_text


def _clean(value: Any) -> Any:
    """JSON has no NaN: a NaN/inf number becomes null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """The rows of a ``metrics.jsonl`` (a torn last line, from a kill, is skipped)."""
    rows = []
    if path.is_file():
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return rows


class RunLog:
    """Appends rows to ``metrics.jsonl`` and, optionally, TensorBoard scalars (rank 0 only).

    Args:
        out_dir: the run's folder.
        resume_step: keep only the rows up to this step (a resumed run), or None (a new run).
        tensorboard: also write event files to ``out_dir/tb``.
    """

    def __init__(self, out_dir: Path, resume_step: int | None, tensorboard: bool = False):
        self.path = out_dir / "metrics.jsonl"
        kept = [r for r in read_metrics(self.path) if resume_step and r["step"] <= resume_step]
        atomic_write_text(self.path, "".join(json.dumps(r) + "\n" for r in kept))
        self.writer = None
        if tensorboard:
            try:  # optional extra: imported only when asked for
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:
                raise UsageError(
                    "log.tensorboard=true needs the tensorboard package: "
                    "pip install 'claravid-toolkit[tensorboard]' (or set log.tensorboard=false)"
                ) from None
            self.writer = SummaryWriter(str(out_dir / "tb"), purge_step=resume_step)

    def write(self, row: dict[str, Any]) -> None:
        """Append one row (flushed: a kill loses at most the line being written)."""
        with self.path.open("a", encoding="utf-8") as f:
            f.write(json.dumps(_clean(row)) + "\n")
        if self.writer is not None:
            for key, value in row.items():
                if key != "step" and isinstance(value, int | float) and value is not None:
                    self.writer.add_scalar(key, value, row["step"])
            for group in ("miou_bins", "boundary_miou_bins"):
                for name, value in (row.get(group) or {}).items():
                    if value is not None:
                        self.writer.add_scalar(f"{group}/{name}", value, row["step"])
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def plot_curves(rows: list[dict[str, Any]], path: Path) -> Path:
    """Training loss and validation mIoU (overall and per complexity bin) against the step."""
    train = [r for r in rows if r.get("loss") is not None]
    val = [r for r in rows if "miou" in r]
    fig = Figure(figsize=(11, 4), layout="constrained")
    ax_loss, ax_miou = fig.subplots(1, 2)
    ax_loss.plot([r["step"] for r in train], [r["loss"] for r in train], lw=1)
    ax_loss.set(xlabel="step", ylabel="training loss", title="loss")
    if train and min(r["loss"] for r in train) > 0:
        ax_loss.set_yscale("log")
    steps = [r["step"] for r in val]
    ax_miou.plot(steps, [r["miou"] for r in val], "o-", color="k", label="all val images")
    for name in (val[-1].get("miou_bins") or {}) if val else ():
        ys = [(r.get("miou_bins") or {}).get(name) for r in val]
        ax_miou.plot(steps, [math.nan if y is None else y for y in ys], ".--", label=name)
    ax_miou.set(xlabel="step", ylabel="mIoU", title="validation mIoU (per delentropy bin)")
    if val:
        ax_miou.legend(fontsize=8)
    ax_miou.grid(alpha=0.3)
    return atomic_save(path, lambda tmp: fig.savefig(tmp, dpi=90))

"""Training: config to data and model, the optimisation loop, checkpoints and resume.

::

    from claravid.train import load_config, train

    cfg = load_config("demo", ["train.steps=100"])
    result = train(cfg)  # out_dir: config.yaml, metrics.jsonl, last.pt, best.pt, curves.png

From the shell: ``claravid-train --config demo`` (``torchrun ... -m claravid.train`` for DDP).
"""

from claravid.train.config import ConfigError, load_config
from claravid.train.loop import RunResult, TrainingDiverged, train

__all__ = ["ConfigError", "RunResult", "TrainingDiverged", "load_config", "train"]

"""Training: config to data and model, the optimisation loop, checkpoints and resume.

::

    from train import load_config, train

    cfg = load_config("demo", ["train.steps=100"])
    result = train(cfg)  # out_dir: config.yaml, metrics.jsonl, last.pt, best.pt, curves.png

From the shell: ``claravid-train --config demo`` (``torchrun ... -m train`` for DDP).
"""

from train.config import ConfigError, load_config
from train.loop import RunResult, TrainingDiverged, train

__all__ = ["ConfigError", "RunResult", "TrainingDiverged", "load_config", "train"]

"""The training config: typed defaults, one YAML file, dotted ``key=value`` overrides.

Merged by OmegaConf structured configs (as DINOv2 does), so there is no hand-written merging::

    cfg = load_config("demo", ["train.steps=200", "data.num_workers=0"])
    cfg.train.lr  # typed: 0.0002

``CONFIG`` is a YAML path or the name of a config shipped with the package (``configs/`` in the
checkout, ``claravid.configs`` in a wheel). An unknown key is an error that names the closest
valid keys; a value of the wrong type or out of range is an error naming the key.

What the config leaves to the model is filled in from the backbone's description
(`claravid.models.backbones.specs`) when it is resolved (:func:`resolve_backbone`), so the resolved
config that every checkpoint keeps records the real numbers: ``data.augment.mean/std`` (the
statistics of the backbone's pre-training: ImageNet's, or SAT-493M's for a ``_sat`` backbone)
and ``val.window`` (the model's natural size: 630 for patches of 14, 640 for 16). Crops and
windows that are not multiples of the backbone's patch size are refused there, naming the two
nearest sizes that are, before any data is read.
"""

from claravid.train.config.checks import (
    check_config,
    check_weights_file,
    derive_steps,
    resolve_backbone,
    statistics_warning,
)
from claravid.train.config.load import find_config, from_plain, load_config
from claravid.train.config.schema import (
    ConfigError,
    StatisticsWarning,
    changed_keys,
    to_plain,
    to_yaml,
    valid_keys,
)

__all__ = [
    "ConfigError",
    "StatisticsWarning",
    "changed_keys",
    "check_config",
    "check_weights_file",
    "derive_steps",
    "find_config",
    "from_plain",
    "load_config",
    "resolve_backbone",
    "statistics_warning",
    "to_plain",
    "to_yaml",
    "valid_keys",
]

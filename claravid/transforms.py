"""The augmentation pipelines under their short public name, as the README imports them::

    from claravid.transforms import eval_transforms, train_transforms

They are defined in :mod:`claravid.data.transforms` (the data layer, beside the datasets that
call them); this module only gives them a name at the package's top, the way ``claravid``
itself gives ``ClaraVidSegmentation`` one.
"""

from __future__ import annotations

from claravid.data.transforms import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    AugmentConfig,
    CropWindow,
    SegmentationTransform,
    augment_config,
    eval_transforms,
    train_transforms,
)

__all__ = [
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "AugmentConfig",
    "CropWindow",
    "SegmentationTransform",
    "augment_config",
    "eval_transforms",
    "train_transforms",
]

"""The statistics an evaluation normalises with are the chosen ones, both of them: a recorded or
named mean that differs from the model's default while the std does not (the case a settings
resolution taking ``mean`` from the default and ``std`` from the choice would get wrong)."""

from types import SimpleNamespace

import pytest

from claravid.eval.inference.sources import ModelSource, resolve_settings
from claravid.models.backbones.specs import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    SAT493M_MEAN,
    SAT493M_STD,
)

#: A mean of their own, ImageNet's std: only the mean tells the choice from the default.
MEAN = [0.5, 0.4, 0.3]


def _norm(mean, std):
    return {"mean": [float(v) for v in mean], "std": [float(v) for v in std]}


@pytest.mark.parametrize("kind", ["checkpoint", "onnx"])
def test_a_recorded_mean_with_the_default_std_is_used_whole(kind):
    # The model states ImageNet's statistics (a segmenter's backbone, an export's record); the
    # training config it came with recorded another mean and the same std.
    model = SimpleNamespace(mean=IMAGENET_MEAN, std=IMAGENET_STD, metadata={}, input_size=None,
                            model_args={})  # fmt: skip
    source = ModelSource(model, kind, f"model.{kind}", 8, 14,
                         {"normalisation": _norm(MEAN, IMAGENET_STD)})  # fmt: skip
    window = resolve_settings(source, window=28).window
    assert window.mean == pytest.approx(MEAN) and window.std == pytest.approx(IMAGENET_STD)


def test_statistics_named_for_a_foreign_onnx_file_are_used_whole():
    assert list(SAT493M_MEAN) != list(IMAGENET_MEAN)
    model = SimpleNamespace(metadata=None, input_size=None, model_args={})
    source = ModelSource(model, "onnx", "foreign.onnx", None, 16, {})
    window = resolve_settings(source, window=32, palette="uavid", statistics="sat493m").window
    # Before the fix a foreign file given --statistics sat493m could run with ImageNet's mean.
    assert window.mean == pytest.approx(SAT493M_MEAN) and window.std == pytest.approx(SAT493M_STD)

"""Test-time augmentation beyond the probabilities: calibration and Boundary IoU score the
averaged probabilities, model files record the protocol, a comparison names a mismatch."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from claravid.eval.analysis.gaps import comparison_warnings, evaluation_protocol
from claravid.eval.inference.augment import TTAConfig
from claravid.eval.inference.image_sums import ImageMeasures, predict_with_confidence
from claravid.eval.inference.run_model import evaluate_model
from claravid.eval.inference.sources import (
    ModelSource,
    checkpoint_defaults,
    onnx_defaults,
    resolve_settings,
)
from claravid.eval.inference.windows import WindowConfig, class_probabilities
from claravid.eval.measures.boundary import boundary_iou
from claravid.eval.measures.calibration_sums import calibration_sums
from claravid.models.export.metadata import build_metadata, metadata_props, read_metadata

MEAN, STD = (0.4, 0.5, 0.6), (0.2, 0.25, 0.3)
TTA = TTAConfig((0.75, 1.0, 1.25), flip=True, rule="mmseg")


def _tiny_conv() -> torch.nn.Module:
    torch.manual_seed(0)
    return torch.nn.Sequential(
        torch.nn.Conv2d(3, 6, 3, padding=1), torch.nn.Tanh(), torch.nn.Conv2d(6, 4, 1)
    ).eval()


def test_calibration_and_boundaries_score_the_averaged_probabilities():
    model, gen = _tiny_conv(), torch.Generator().manual_seed(1)
    image = torch.randint(0, 256, (3, 30, 44), dtype=torch.uint8, generator=gen)
    mask = torch.randint(0, 4, (30, 44), generator=gen)
    config = WindowConfig(size=(16, 16), stride=(11, 11), mean=MEAN, std=STD, tta=TTA)
    probs = class_probabilities(model, image, config)
    prediction, confidence = predict_with_confidence(model, image, config, True)
    assert torch.equal(prediction, probs.argmax(0))
    assert torch.equal(confidence, probs.max(0).values)
    # The single-copy prediction differs here: the averaged one is what gets scored.
    single = WindowConfig(size=(16, 16), stride=(11, 11), mean=MEAN, std=STD)
    plain = predict_with_confidence(model, image, single, True)[0]
    assert not torch.equal(plain, prediction)
    sample = {"image": image, "mask": mask, "path": "a.png"}
    (score,) = evaluate_model(model, [sample], 4, config,
                              measures=ImageMeasures(boundary=True, calibration=True))  # fmt: skip
    ids = probs.argmax(0).to(torch.uint8)
    count, conf_sum, correct = calibration_sums(probs.max(0).values, ids, mask, 15, 4)
    np.testing.assert_allclose(score.calibration, np.stack([count, conf_sum, correct]))
    inter, union = boundary_iou(ids, mask, 4)
    np.testing.assert_array_equal(score.boundary, np.stack([inter, union]))


def test_training_records_the_protocol_in_checkpoint_and_onnx_metadata():
    config = {"val": {"window": 32, "stride": 21, "tta_scales": [0.9, 1.0, 1.1],
                      "tta_flip": True, "tta_rule": "dinov3", "tta_size": 512}}  # fmt: skip
    record = {"rule": "dinov3", "scales": [0.9, 1.0, 1.1], "flip": True, "size": 512}
    assert checkpoint_defaults({"config": config})["tta"] == record
    document = build_metadata({}, patch_size=16, num_classes=4, config=config)
    assert onnx_defaults(read_metadata(metadata_props(document)))["tta"] == record
    # No val.tta_scales: nothing recorded, one copy.
    assert "tta" not in checkpoint_defaults({"config": {"val": {"window": 32}}})


def test_a_recorded_protocol_is_used_unless_a_flag_says_otherwise():
    record = TTA.describe()
    model = SimpleNamespace(mean=MEAN, std=STD)
    source = ModelSource(model, "checkpoint", "m.pt", 4, None, {"tta": record})  # type: ignore[arg-type]
    run = resolve_settings(source, window=16)
    assert run.window.tta == TTA and run.origins["tta"] == "checkpoint"
    assert run.describe()["tta"] == record
    off = resolve_settings(source, window=16, tta=False)
    assert off.window.tta is None and off.origins["tta"] == "flag"
    other = TTAConfig.preset("dinov3")
    assert resolve_settings(source, window=16, tta=other).window.tta == other


def _report(tta):
    window = {"size": [640, 640], "stride": [426, 426], "scale": 0.5, "tta": tta}
    return {
        "palette": "uavid",
        "classes": ["a"],
        "bins": [],
        "source": {"binning": {}, "window": window},
    }


def test_a_comparison_of_two_protocols_says_so():
    plain, augmented = _report(None), _report(TTA.describe())
    assert comparison_warnings([plain, _report(None)], ["a", "b"]) == []
    (warning,) = comparison_warnings([plain, augmented], ["plain", "tta"])
    assert warning == (
        "evaluation protocols differ: plain windows 640x640 every 426x426, scale 0.5, one copy "
        "(no test-time augmentation); tta windows 640x640 every 426x426, scale 0.5, test-time "
        "augmentation (mmseg rule): ratios 0.75, 1, 1.25 and the mirror; the gaps include the "
        "augmentation's effect"
    )
    assert evaluation_protocol({"source": {"kind": "predictions"}}) is None


def test_the_settings_refuse_what_is_not_a_protocol():
    from claravid.eval.settings import InferenceSettings

    with pytest.raises(ValueError, match="tta must be a TTAConfig"):
        InferenceSettings(tta="dinov3")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="tta must be a TTAConfig"):
        InferenceSettings(tta=True)


def test_the_flags_make_the_settings():
    import argparse

    from claravid.eval.inference.augment import tta_from_flags
    from claravid.infra.cli import ratio_list

    assert tta_from_flags(None) is None  # the model file's, else none
    assert tta_from_flags("none") is False
    assert tta_from_flags("dinov3") == TTAConfig.preset("dinov3")
    assert tta_from_flags("mmseg", (0.5, 1.0)) == TTAConfig((0.5, 1.0), True, "mmseg")
    assert tta_from_flags(None, (0.9, 1.1), True, 512) == TTAConfig((0.9, 1.1), True, "dinov3", 512)
    assert tta_from_flags(None, None, True) == TTAConfig((1.0,), True)
    assert ratio_list("0.9, 1,1.1") == (0.9, 1.0, 1.1)
    with pytest.raises(ValueError, match="--tta none turns"):
        tta_from_flags("none", (1.0,))
    with pytest.raises(ValueError, match="dinov3 rule"):
        tta_from_flags("mmseg", size=512)
    for bad in ("", "0.9,x", "0,1", "nan"):
        with pytest.raises(argparse.ArgumentTypeError, match="ratios"):
            ratio_list(bad)


def test_an_onnx_file_averages_the_same_probabilities(model_files, model_onnx):
    """An ONNX source (numpy out, patch multiples in) gives the checkpoint's TTA probabilities,
    its small copies' windows padded to the patch grid the same way."""
    from claravid import models

    runner = models.OnnxSegmenter(model_onnx["onnx"])
    image = torch.randint(0, 256, (3, 48, 64), dtype=torch.uint8,
                          generator=torch.Generator().manual_seed(6))  # fmt: skip
    config = WindowConfig(size=(42, 56), tta=TTAConfig((0.5, 1.0), True, "mmseg"))
    want = class_probabilities(model_files["model"], image, config)
    got = class_probabilities(runner, image, config)
    assert (got - want).abs().max() <= 1e-4

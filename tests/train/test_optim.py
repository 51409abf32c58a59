"""Learning-rate schedule values and parameter groups."""

import math

import pytest

from claravid import models
from claravid.train.config import load_config
from claravid.train.optim import build_optimizer, lr_factor
from tests.tiny import MODEL


def test_warmup_then_poly_and_cosine():
    assert lr_factor(0, 100, 10, "poly", 1.0, 0.0) == pytest.approx(0.1)
    assert lr_factor(9, 100, 10, "poly", 1.0, 0.0) == pytest.approx(1.0)
    assert lr_factor(10, 100, 10, "poly", 1.0, 0.0) == pytest.approx(1.0)
    assert lr_factor(55, 100, 10, "poly", 1.0, 0.0) == pytest.approx(0.5)  # linear at power 1
    assert lr_factor(55, 100, 10, "poly", 2.0, 0.0) == pytest.approx(0.25)
    assert lr_factor(55, 100, 10, "cosine", 1.0, 0.0) == pytest.approx(0.5)
    assert lr_factor(32.5, 100, 10, "cosine", 1.0, 0.0) == pytest.approx(
        0.5 * (1 + math.cos(math.pi / 4))
    )
    assert lr_factor(100, 100, 10, "cosine", 1.0, 0.1) == pytest.approx(0.1)  # floor


def test_frozen_backbone_is_not_optimised():
    model = models.build_model("dinov2_vits14", 3, **MODEL)
    cfg = load_config("demo", ["train.lr=0.01", "train.weight_decay=0.5"])
    opt = build_optimizer(model, cfg)
    params = {id(p) for g in opt.param_groups for p in g["params"]}
    assert params == {id(p) for p in model.head.parameters()}
    for group in opt.param_groups:
        assert group["lr"] == 0.01
        decays = all(p.ndim > 1 for p in group["params"])
        assert group["weight_decay"] == (0.5 if decays else 0.0)

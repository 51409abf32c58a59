"""The public API as a user's type checker sees it: ``make lint`` runs mypy over this file, and
nothing runs it. Every name below is one of a package's lazy exports (PEP 562); if a package hid
its names from type checkers again, they would be ``Any`` here and the ``assert_type`` lines
would fail. The last lines check that a misspelt name is an error, not ``Any``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from typing_extensions import assert_type

import claravid
import claravid.dsp
import claravid.eval
import claravid.models
from claravid import ClaraVidSegmentation, DatasetNotFoundError, Palette, load_palette
from claravid.dsp import Profile, delentropy, fit_profile
from claravid.eval import WindowConfig, mean_iou
from claravid.models import (
    DPTHead,
    LinearHead,
    OnnxSegmenter,
    Segmenter,
    UperNetHead,
    build_model,
    load_checkpoint,
)
from claravid.models.heads.protocol import Head
from claravid.train import load_config


def the_names_keep_their_types(gray: np.ndarray, confusion: np.ndarray) -> None:
    assert_type(load_palette("uavid"), Palette)
    assert_type(ClaraVidSegmentation("/data/claravid")[0], dict[str, Any])
    assert_type(DatasetNotFoundError("ClaraVid root"), DatasetNotFoundError)
    assert_type(fit_profile([4.0, 4.5]), Profile)
    assert_type(delentropy(gray), float)
    assert_type(mean_iou(confusion), float)
    assert_type(WindowConfig(size=(518, 518)).scale, float)
    model = build_model("dinov2_vits14", num_classes=8)
    assert_type(model, Segmenter)
    assert_type(model.forward(torch.zeros(1, 3, 518, 518)), torch.Tensor)
    assert_type(load_checkpoint("best.pt"), Segmenter)
    assert_type(OnnxSegmenter("model.onnx").window, tuple[int, int] | None)
    assert_type(load_config("demo"), DictConfig)


def the_heads_are_heads() -> list[Head]:
    # Structural: mypy checks each head's forward and num_classes against the protocol.
    return [DPTHead(32, 8), LinearHead(32, 8), UperNetHead(32, 8)]


def a_misspelt_name_is_an_error() -> None:
    # Were a module-level __getattr__ visible to the checker, these would be Any and each
    # ignore unused, which `warn_unused_ignores` reports.
    claravid.Pallete  # type: ignore[attr-defined]  # noqa: B018
    claravid.dsp.delentropi  # type: ignore[attr-defined]  # noqa: B018
    claravid.eval.WindowConfg  # type: ignore[attr-defined]  # noqa: B018
    claravid.models.build_modle  # type: ignore[attr-defined]  # noqa: B018
    # Names that left the public API (one name per concept) are errors too, not Any.
    claravid.eval.evaluate_model  # type: ignore[attr-defined]  # noqa: B018
    claravid.eval.merge_results  # type: ignore[attr-defined]  # noqa: B018
    claravid.models.official_to_hf  # type: ignore[attr-defined]  # noqa: B018

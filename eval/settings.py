"""The settings of an evaluation run, grouped by what they choose (:mod:`claravid.eval.run`).

- :class:`DataChoice`: which images (root, dataset kind, split, palette, ClaraVid selection);
- :class:`InferenceSettings`: how a model runs (windows, batch, device, precision, provider);
- :class:`ReportSettings`: how the report is made (bins, groups, measures, tiles, intervals);
- :class:`Evaluation`: what a run returns.

A field left None takes what the model file recorded, else the default, so
``evaluate(out, checkpoint=...)`` evaluates a checkpoint the way it was trained.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.table import EvalResult
from claravid.eval.analysis.units import check_unit
from claravid.infra.cli import UsageError

#: ClaraVid selection settings a checkpoint records and ``DataChoice.selection`` replaces.
SELECTION = ("missions", "altitude", "direction")


@dataclass(frozen=True)
class DataChoice:
    """The images to evaluate; None: what the model recorded, else the default.

    Attributes:
        root: the dataset root (``--data``).
        dataset: ``claravid``, ``uavid`` or ``folder`` (default ``claravid``).
        split: ``train``/``val``/``test``/``all`` or a split file (default ``val``).
        palette: a palette name or YAML file.
        masks: the label folder mirroring ``root`` (``folder`` only).
        selection: ClaraVid ``missions``/``altitude``/``direction`` lists, replacing the
            checkpoint's.
    """

    root: str | Path | None = None
    dataset: str | None = None
    split: str | None = None
    palette: str | Path | None = None
    masks: str | Path | None = None
    selection: dict[str, list[str]] = field(default_factory=dict)


@dataclass(frozen=True)
class InferenceSettings:
    """How a model runs; None: what the model file recorded, else the default.

    Attributes:
        window: the sliding window (height, width) or N for N x N.
        stride: the window step (height, width) or N (default 2/3 of the window).
        scale: resize images first (default 1).
        batch_size: windows per forward pass (default 4).
        device: ``cpu``, ``cuda`` or ``cuda:N`` (default: CUDA when available).
        precision: ``auto``, ``fp32``, ``bf16`` or ``fp16`` (PyTorch models).
        provider: ONNX Runtime provider (ONNX models).
    """

    window: int | tuple[int, int] | None = None
    stride: int | tuple[int, int] | None = None
    scale: float | None = None
    batch_size: int | None = None
    device: str | None = None
    precision: str = "auto"
    provider: str | None = None


@dataclass(frozen=True)
class ReportSettings:
    """How the report is made from the per-image table.

    Attributes:
        bins: K quantile bins of delentropy (ignored with ``edges``).
        edges: fixed delentropy edges.
        group_by: rows per ``mission``, ``viewpoint``, ``sequence`` or ``folder``.
        measures: complexity measures, ``delent`` first.
        tiles: also bin tiles of about this many pixels (model and label-map evaluations).
        hardest: overlays of the K hardest images.
        bootstrap: resamples, level and seed of the intervals (its ``cluster`` is replaced by
            ``cluster``).
        cluster: the resampled unit; None: the data's default.
    """

    bins: int = 3
    edges: Sequence[float] | None = None
    group_by: str | None = None
    measures: Sequence[str] = ("delent",)
    tiles: int | None = None
    hardest: int = 4
    bootstrap: Bootstrap = field(default_factory=Bootstrap)
    cluster: str | None = None

    def intervals(self, attributes: dict[str, list[str]], default: str) -> Bootstrap:
        """The bootstrap settings for images with these ``attributes`` (the ``default`` unit
        when ``cluster`` is None), the unit checked against what the images carry."""
        unit = check_unit(attributes, self.cluster or default)
        return dataclasses.replace(self.bootstrap, cluster=unit)

    def check_bins(self, num_images: int) -> None:
        """Fail when there are more quantile bins than images.

        Raises:
            UsageError: ``bins`` > ``num_images`` without fixed edges.
        """
        if self.edges is None and self.bins > num_images:
            raise UsageError(
                f"{self.bins} bins for {num_images} images: use --bins {num_images} or fewer"
            )


@dataclass
class Evaluation:
    """What a run returns.

    Attributes:
        output: the report folder.
        report: the report (``report.json``); None on a ``torchrun`` rank other than 0.
        result: the per-image table (None for ``--scores`` and on the other ranks).
        skipped: images left out for want of a prediction (``allow_missing``).
        text: the report's Markdown (``--scores``).
    """

    output: Path
    report: dict[str, Any] | None
    result: EvalResult | None = None
    skipped: list[str] = field(default_factory=list)
    text: str = ""

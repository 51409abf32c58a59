"""The settings of an evaluation run, grouped by what they choose (:mod:`claravid.eval.run`).

- :class:`DataChoice`: which images (root, dataset kind, split, palette, ClaraVid selection);
- :class:`InferenceSettings`: how a model runs (windows, batch, device, precision, provider);
- :class:`ReportSettings`: how the report is made (bins, groups, measures, tiles, intervals,
  and which measures beyond mIoU: boundaries, calibration, cross-view consistency);
- :class:`Evaluation`: what a run returns.

A field left None takes what the model file recorded, else the default, so
``evaluate(out, checkpoint=...)`` evaluates a checkpoint the way it was trained.

Each class checks its fields when it is made (``__post_init__``), with the messages
``claravid-eval`` prints: the command line builds these very objects from its flags, so a
mistake is refused the same way, before any work, from Python and from the shell.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from claravid.dsp.tiles import MIN_TILE_SIZE
from claravid.eval.analysis.bins import parse_edges
from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.analysis.complexity_measures import parse_measures
from claravid.eval.analysis.table import EvalResult
from claravid.eval.analysis.units import CLUSTER_UNITS, DATASETS, GROUP_BY, check_unit
from claravid.eval.inference.augment import TTAConfig
from claravid.infra.cli import UsageError, selection_names
from claravid.infra.precision import PRECISIONS
from claravid.models.backbones.specs import NAMED_STATISTICS
from claravid.models.export.runtime import PROVIDERS

#: ClaraVid selection settings a checkpoint records and ``DataChoice.selection`` replaces.
SELECTION = ("missions", "altitude", "direction")


def _one_of(value: Any, choices: Sequence[str], flag: str, what: str) -> None:
    if value is not None and value not in choices:
        raise ValueError(f"unknown {flag} {value!r} ({what}); use one of {', '.join(choices)}")


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _size(value: Any, flag: str) -> int | tuple[int, int] | None:
    """A window or stride: None, N, or (height, width), positive integers."""
    if value is None:
        return None
    pair = (value, value) if _is_int(value) else value
    if (
        not isinstance(pair, Sequence)
        or isinstance(pair, str)
        or len(pair) != 2
        or not all(_is_int(v) and v >= 1 for v in pair)
    ):
        raise ValueError(
            f"{flag} must be a positive integer N or a pair (height, width) of them, got {value!r}"
        )
    return int(value) if _is_int(value) else (int(pair[0]), int(pair[1]))


def selection_lists(selection: Mapping[str, Any]) -> dict[str, list[str]]:
    """ClaraVid ``missions``/``altitude``/``direction``, each a comma-separated string or a list,
    as lists of names (blank names dropped).

    Raises:
        ValueError: an unknown key, or a selection with no name left.
    """
    if not isinstance(selection, Mapping):
        raise TypeError(f"selection must be a dict such as {{'missions': ['rural_1']}}, got "
                        f"{type(selection).__name__}")  # fmt: skip
    out = {}
    for name, given in selection.items():
        if name not in SELECTION:
            raise ValueError(
                f"unknown selection {name!r}: the ClaraVid selection is {', '.join(SELECTION)}"
            )
        out[name] = selection_names(name, given)
    return out


def check_type(value: Any, kind: type, name: str, example: str) -> None:
    """Refuse an argument of the wrong type with a message that shows the right one.

    Raises:
        TypeError: ``value`` is not a ``kind`` (e.g. ``evaluate(data="root")``).
    """
    if value is not None and not isinstance(value, kind):
        article = "an" if kind.__name__[0] in "AEIOU" else "a"
        raise TypeError(
            f"{name} must be {article} {kind.__name__} (e.g. {example}), got "
            f"{type(value).__name__} {value!r}"
        )


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
    split: str | Path | None = None
    palette: str | Path | None = None
    masks: str | Path | None = None
    selection: dict[str, list[str]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _one_of(self.dataset, DATASETS, "--dataset", "the kind of data")
        for name in ("root", "split", "palette", "masks"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, (str, Path)):
                raise TypeError(f"{name} must be a str or a Path, got {type(value).__name__}")
        object.__setattr__(self, "selection", selection_lists(self.selection or {}))


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
        statistics: the input statistics of an ONNX file exported elsewhere, which records
            none: ``imagenet`` or ``sat493m`` (required for such a file, refused for any other:
            a checkpoint or a claravid export carries its own).
        tta: test-time augmentation (scales and mirror, e.g. ``TTAConfig.preset("dinov3")``);
            None: what the model file recorded (training's ``val.tta_*``), else none; False:
            none, whatever the file recorded.
        gsd: the data's ground sampling distance (metres per pixel): the images are resized to
            the model's recorded GSD (scale = gsd / the model's), in place of ``scale``.
    """

    window: int | tuple[int, int] | None = None
    stride: int | tuple[int, int] | None = None
    scale: float | None = None
    batch_size: int | None = None
    device: str | None = None
    precision: str = "auto"
    provider: str | None = None
    statistics: str | None = None
    tta: TTAConfig | bool | None = None
    gsd: float | None = None

    def __post_init__(self) -> None:
        if self.tta is not None and self.tta is not False and not isinstance(self.tta, TTAConfig):
            raise ValueError(
                f"tta must be a TTAConfig (e.g. TTAConfig.preset('dinov3')), False (none) or "
                f"None (the model file's), got {self.tta!r}"
            )
        object.__setattr__(self, "window", _size(self.window, "--window"))
        if self.gsd is not None and not (
            isinstance(self.gsd, (int, float)) and math.isfinite(self.gsd) and self.gsd > 0
        ):
            raise ValueError(f"--gsd must be metres per pixel > 0, got {self.gsd!r}")
        object.__setattr__(self, "stride", _size(self.stride, "--stride"))
        if self.scale is not None and not (
            isinstance(self.scale, (int, float)) and math.isfinite(self.scale)
            and 0 < self.scale <= 8
        ):  # fmt: skip
            raise ValueError(f"--scale must be in (0, 8], got {self.scale!r}")
        if self.batch_size is not None and not (_is_int(self.batch_size) and self.batch_size >= 1):
            raise ValueError(f"--batch-size must be at least 1, got {self.batch_size!r}")
        if self.precision not in PRECISIONS:
            raise ValueError(
                f"precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}"
            )
        _one_of(self.provider, tuple(PROVIDERS), "--provider", "the ONNX Runtime provider")
        _one_of(self.statistics, tuple(NAMED_STATISTICS), "--statistics", "input statistics")


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
        boundary: Boundary IoU per class (None: on; False: off).
        calibration: ECE, MCE and the reliability diagram (None: on where the source has
            scores, a checkpoint or an ONNX file; True: required, refused for label maps;
            False: off).
        consistency: cross-view consistency between consecutive frames of a pass (None: on
            where the data has depth and poses, ClaraVid; True: required, refused for other
            data; False: off).
        classes: a subset of the palette's classes (names, or one comma-separated string):
            every row also gets ``miou_classes``, the mIoU over them, with its interval.
    """

    bins: int = 3
    edges: Sequence[float] | None = None
    group_by: str | None = None
    measures: Sequence[str] = ("delent",)
    tiles: int | None = None
    hardest: int = 4
    bootstrap: Bootstrap = field(default_factory=Bootstrap)
    cluster: str | None = None
    boundary: bool | None = None
    calibration: bool | None = None
    consistency: bool | None = None
    classes: Sequence[str] | None = None

    def __post_init__(self) -> None:
        if self.classes is not None:
            items = self.classes.split(",") if isinstance(self.classes, str) else self.classes
            names = [str(c).strip() for c in items if str(c).strip()]
            if not names:
                raise ValueError(
                    "--classes is empty; give class names, e.g. --classes Road,Building"
                )
            object.__setattr__(self, "classes", names)
        for name in ("boundary", "calibration", "consistency"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, bool):
                raise ValueError(
                    f"{name} must be True, False or None (on where possible), got {value!r}"
                )
        if not _is_int(self.bins) or self.bins < 1:
            raise ValueError(f"--bins must be at least 1, got {self.bins!r}")
        if self.edges is not None:
            object.__setattr__(self, "edges", parse_edges(self.edges))
        _one_of(self.group_by, GROUP_BY, "--group-by", "the rows of the report")
        # Bins and tiles are made of delentropy: it is always computed, first (as --measures).
        object.__setattr__(self, "measures", tuple(parse_measures(self.measures)))
        if self.tiles is not None and not (_is_int(self.tiles) and self.tiles >= MIN_TILE_SIZE):
            raise ValueError(
                f"--tiles must be at least {MIN_TILE_SIZE} pixels (e.g. 630), got {self.tiles!r}"
            )
        if not _is_int(self.hardest) or self.hardest < 0:
            raise ValueError(f"--hardest must be >= 0, got {self.hardest!r}")
        if not isinstance(self.bootstrap, Bootstrap):
            raise ValueError(
                f"bootstrap must be a Bootstrap (e.g. Bootstrap(resamples=1000)), got "
                f"{self.bootstrap!r}"
            )
        if self.cluster is not None and self.cluster not in CLUSTER_UNITS:
            raise ValueError(
                f"unknown --cluster {self.cluster!r} (the resampled unit); use one of "
                f"{', '.join(CLUSTER_UNITS)}"
            )

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
        result: the per-image table (None for ``scores`` and on the other ranks).
        skipped: images left out for want of a prediction (``allow_missing``).
        text: the report's Markdown (``scores``).
    """

    output: Path
    report: dict[str, Any] | None
    result: EvalResult | None = None
    skipped: list[str] = field(default_factory=list)
    text: str = ""


def check_classes(classes: Sequence[str] | None, names: Sequence[str]) -> None:
    """Refuse a ``--classes`` subset that names a class the palette does not have.

    Raises:
        UsageError: one line naming the unknown classes and the palette's.
    """
    from claravid.eval.analysis.predictable import subset_mask

    try:
        subset_mask(list(names), classes)
    except ValueError as exc:
        raise UsageError(str(exc)) from None

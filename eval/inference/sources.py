"""Where predictions come from (a PyTorch checkpoint or an ONNX file), and how they are run.

:func:`resolve_settings` is the one place that decides how a model is run, for
``claravid-eval`` and ``claravid-predict`` alike: window, stride, scale, batch size, palette
and input normalisation, each from the command line, else from what the model file records (a
checkpoint's training config, or an ONNX file's ``claravid`` metadata), else the default; the
report records each value and where it came from.

A training checkpoint (``claravid.models.save_checkpoint`` with the resolved training ``config``
as an extra entry) also says which data and palette it was trained for; :func:`checkpoint_defaults`
reads those defensively, so an older or plain model checkpoint still works when the command
line gives ``--data`` and ``--palette``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from claravid.eval.inference.augment import TTAConfig
from claravid.eval.inference.windows import Model, WindowConfig, model_statistics
from claravid.infra.cli import UsageError
from claravid.models.backbones.specs import NAMED_STATISTICS
from claravid.models.export.metadata import (
    backbone_statistics,
    config_get,
    normalisation_from_config,
    window_from_config,
)
from claravid.models.grid import PAPER_WINDOW, natural_size
from claravid.models.heads.specs import HEADS, check_input_size

DEFAULT_SCALE = 1.0
DEFAULT_BATCH = 4


@dataclass
class ModelSource:
    """A loaded model and what the report says about it."""

    model: Model
    kind: str  # "checkpoint" or "onnx"
    path: str
    num_classes: int | None
    patch_size: int | None
    defaults: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> dict[str, Any]:
        """The report's ``source`` entries for the model."""
        return {"kind": self.kind, "path": self.path}


#: Every training-config key :func:`checkpoint_defaults` reads, by the name it gives it. eval
#: cannot import the training schema (train imports eval), so tests/train checks each path
#: against ``claravid.train.config``: renaming a key there fails a test instead of silently
#: dropping a default here.
TRAINING_KEYS: dict[str, tuple[str, ...]] = {
    "val_dataset": ("data", "val_dataset"),
    "dataset": ("data", "dataset"),
    "val_root": ("data", "val_root"),
    "root": ("data", "root"),
    "palette": ("data", "palette"),
    "val_split": ("data", "val_split"),
    "split": ("data", "split"),
    "missions": ("data", "missions"),
    "altitude": ("data", "altitude"),
    "direction": ("data", "direction"),
    "augment": ("data", "augment"),
}
#: The fields of ``data.split`` that make ``--split val`` the split training held out.
SPLIT_FIELDS = ("block_size", "fractions", "seed", "val_missions", "test_missions")


def checkpoint_defaults(checkpoint: Mapping[str, Any]) -> dict[str, Any]:
    """What a training checkpoint says about evaluating it: its validation data and windows.

    Reads the resolved training config (``checkpoint["config"]``) at :data:`TRAINING_KEYS`:
    the validation dataset (``data.val_dataset``, ``data.val_root`` or ``data.root``,
    ``data.val_split``), the palette, the ClaraVid selection and split settings (so ``--split
    val`` is the very split training held out), and the validation windows (``val.window``,
    ``val.stride``, ``val.scale``, ``val.batch_size``) and the input normalisation
    (``data.augment.mean/std``). Anything missing or of the wrong type is left out, so the
    command line's values or the defaults (the model's natural window, its own statistics)
    apply.
    """
    config = checkpoint.get("config")

    def read(name: str) -> Any:
        return config_get(config, *TRAINING_KEYS[name])

    out: dict[str, Any] = {}
    dataset = read("val_dataset") or read("dataset")
    if dataset in ("claravid", "uavid", "folder"):
        out["dataset"] = dataset
    for name, value in {
        "data": read("val_root") or read("root"),
        "palette": read("palette"),
        "split": read("val_split"),
    }.items():
        if isinstance(value, str) and value:
            out[name] = value
    split = read("split")
    if isinstance(split, Mapping):
        out["split_config"] = {k: split[k] for k in SPLIT_FIELDS if k in split}
    for name in ("missions", "altitude", "direction"):
        value = read(name)
        if isinstance(value, list | tuple | str):
            out[name] = value
    window = window_from_config(config)  # the same reading as the ONNX metadata's
    for name, key in (("window", "size"), ("stride", "stride")):
        if key in window:
            h, w = window[key]
            out[name] = h if h == w else (h, w)
    for name in ("scale", "batch_size", "tta"):
        if name in window:
            out[name] = window[name]
    augment = read("augment")
    if isinstance(augment, Mapping) and any(augment.get(k) is not None for k in ("mean", "std")):
        # What training normalised with; a key it left unset is the backbone's (never ImageNet's
        # for a SAT backbone).
        stats = backbone_statistics(checkpoint.get("model_args"))
        out["normalisation"] = normalisation_from_config(config, stats)
    gsd = model_gsd(checkpoint.get("gsd"))
    if gsd is not None:
        out["gsd"] = gsd
    return out


def model_gsd(record: Any) -> float | None:
    """Metres per pixel of a checkpoint's or ONNX file's ``gsd`` record; None when absent or
    unusable."""
    value = record.get("metres_per_pixel") if isinstance(record, Mapping) else None
    if isinstance(value, int | float) and not isinstance(value, bool) and value > 0:
        return float(value)
    return None


def onnx_defaults(metadata: Mapping[str, Any] | None) -> dict[str, Any]:
    """What an ONNX file's ``claravid`` metadata says about running it (as
    :func:`checkpoint_defaults` for a checkpoint); empty for a file exported elsewhere."""
    if not metadata:
        return {}
    out: dict[str, Any] = {}
    window = metadata.get("window") or {}
    for name, key in (("window", "size"), ("stride", "stride")):
        if key in window:
            out[name] = tuple(window[key])
    for name in ("scale", "batch_size", "tta"):
        if name in window:
            out[name] = window[name]
    palette = metadata.get("palette")
    if palette:
        out["palette"] = palette.get("name") or None
        out["palette_info"] = palette
    if metadata.get("normalisation"):
        out["normalisation"] = metadata["normalisation"]
    out["gsd"] = model_gsd(metadata.get("gsd"))
    return {k: v for k, v in out.items() if v is not None}


@dataclass
class RunSettings:
    """How a model is run, each value with where it came from.

    Attributes:
        window: the sliding windows (size, stride, scale, batch size).
        palette: a palette name or YAML path (None: the data's default, or none at all).
        palette_info: the palette recorded in an ONNX file (names, colours), when any.
        normalisation: ``{"mean", "std", ...}`` of the input.
        origins: ``{setting: "flag" | "checkpoint" | "onnx" | "default" | "gsd"}``.
        gsd: metres per pixel of the model's training images (``model``, None: not recorded)
            and of the evaluated data (``data``: stated with ``--gsd``, else None).
    """

    window: WindowConfig
    palette: str | None
    palette_info: dict[str, Any] | None
    normalisation: dict[str, Any]
    origins: dict[str, str]
    gsd: dict[str, float | None] = field(default_factory=lambda: {"model": None, "data": None})

    def describe(self) -> dict[str, Any]:
        """The report's ``source["settings"]``: every value used and where it came from."""
        w = self.window
        assert w.size is not None and w.stride is not None  # resolved for the model
        return {
            "window": list(w.size),
            "stride": list(w.stride),
            "scale": w.scale,
            "batch_size": w.batch_size,
            "palette": self.palette,
            "normalisation": {k: self.normalisation[k] for k in ("mean", "std")},
            "tta": None if w.tta is None else w.tta.describe(),
            "gsd": dict(self.gsd),
            "from": dict(self.origins),
        }


def _pair(value: Any) -> tuple[int, int] | None:
    if value is None:
        return None
    return (value, value) if isinstance(value, int) else (int(value[0]), int(value[-1]))


def resolve_settings(
    source: ModelSource,
    *,
    window: int | tuple[int, int] | None = None,
    stride: int | tuple[int, int] | None = None,
    scale: float | None = None,
    batch_size: int | None = None,
    palette: str | Path | None = None,
    precision: str = "auto",
    statistics: str | None = None,
    tta: TTAConfig | bool | None = None,
    gsd: float | None = None,
) -> RunSettings:
    """Window, stride, scale, batch size, palette and normalisation: flag, else the model
    file's record, else the default. A ``--stride`` recorded for another window is dropped
    when ``--window`` is given (the default stride follows the window). The default window is
    the model's natural size (630 for patches of 14, 640 for 16: `natural_size`); the default
    normalisation is the model's own (a checkpoint's backbone statistics, an export's record).
    An ONNX file exported elsewhere records none of these: it needs ``palette``, ``window``
    (unless its input size is fixed) and ``statistics`` (a name of `NAMED_STATISTICS`), which
    no other source takes. ``gsd`` states the data's ground sampling distance (metres per
    pixel): the images are then resized to the model's (scale = gsd / the model's recorded GSD).

    Raises:
        UsageError: a window other than a fixed-size ONNX file's input size; an ONNX file
            without claravid metadata and no ``--palette``/``--window``/``--statistics`` (the
            message names what is missing); ``--statistics`` for a file that records its own;
            an unknown statistics name; a window that is not a multiple of the patch size;
            ``gsd`` with ``scale``, or for a model that records no GSD.
    """
    recorded = source.defaults
    kind = source.kind
    fixed = getattr(source.model, "input_size", None)
    _check_foreign(source, palette, window or fixed, statistics)
    origins: dict[str, str] = {}

    def pick(name: str, flag: Any, record: Any, default: Any) -> Any:
        for value, origin in ((flag, "flag"), (record, kind), (default, "default")):
            if value is not None:
                origins[name] = origin
                return value
        origins[name] = "default"
        return None

    natural = natural_size(source.patch_size) if source.patch_size else PAPER_WINDOW
    size = pick("window", _pair(window), fixed or _pair(recorded.get("window")), (natural,) * 2)
    if fixed is not None and tuple(size) != tuple(fixed):
        raise UsageError(
            f"the ONNX model takes {fixed[1]}x{fixed[0]} (WxH) inputs only: use --window "
            f"{fixed[1]}x{fixed[0]} or re-export with --dynamic"
        )
    # A recorded stride belongs to the recorded window: with --window the default follows it.
    record_stride = None if window is not None else _pair(recorded.get("stride"))
    step = pick("stride", _pair(stride), record_stride, None)
    name = pick("palette", palette, recorded.get("palette"), None)
    info = recorded.get("palette_info") if palette is None else None
    named, default_norm = _normalisations(source, statistics)
    normalisation = pick("normalisation", named, recorded.get("normalisation"), default_norm)
    recorded_tta = recorded.get("tta")
    chosen = pick("tta", tta, TTAConfig.from_record(recorded_tta) if recorded_tta else None, None)
    model_gsd = recorded.get("gsd")
    if gsd is not None:
        scale = _gsd_scale(gsd, model_gsd, scale, source.path)
    config = WindowConfig(
        tta=chosen if isinstance(chosen, TTAConfig) else None,
        size=size,
        stride=step,
        scale=pick("scale", scale, recorded.get("scale"), DEFAULT_SCALE),
        batch_size=pick("batch_size", batch_size, recorded.get("batch_size"), DEFAULT_BATCH),
        precision=precision,
        mean=tuple(normalisation["mean"]),
        std=tuple(normalisation["std"]),
    )
    _check_window(source, config, origins["window"])
    if gsd is not None:
        origins["scale"] = "gsd"
    return RunSettings(
        config, name, info, normalisation, origins, {"model": model_gsd, "data": gsd}
    )


def _gsd_scale(gsd: float, model_gsd: float | None, scale: float | None, path: str) -> float:
    """The resize that brings data of ``gsd`` metres per pixel to the model's GSD."""
    if scale is not None:
        raise UsageError(
            "give --gsd or --scale, not both (--gsd sets the scale to match the model)"
        )
    if model_gsd is None:
        raise UsageError(
            f"{path} records no ground sampling distance (trained on data without one: set "
            "data.gsd when training), so --gsd cannot match it; use --scale instead"
        )
    if not (gsd > 0 and math.isfinite(gsd)):
        raise UsageError(f"--gsd must be metres per pixel > 0, got {gsd}")
    return gsd / model_gsd


def _normalisations(
    source: ModelSource, statistics: str | None
) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """(the named statistics of a foreign ONNX file, or None; the default: the model's own, a
    checkpoint's backbone statistics, else ImageNet's)."""
    default = normalisation_from_config(None)
    mean, std = model_statistics(source.model)
    if mean is not None:  # the model's own: a checkpoint's backbone (the model owns them)
        default = {**default, "mean": [float(v) for v in mean], "std": [float(v) for v in std]}
    named = None
    if statistics is not None:  # a foreign ONNX file: the user's word, never a guess
        named = normalisation_from_config(None, default=NAMED_STATISTICS[statistics])
    return named, default


def _check_window(source: ModelSource, config: WindowConfig, origin: str) -> None:
    """The window on the model's patch grid and no smaller than its head takes.

    Raises:
        UsageError: one line, saying where the window came from (``origin``).
    """
    if not source.patch_size:
        return
    try:
        config.check_patch(source.patch_size)
        head = (getattr(source.model, "model_args", None) or {}).get("head")
        if head in HEADS:  # an ONNX file's graph would fail inside ONNX Runtime
            assert config.size is not None
            height, width = config.size
            check_input_size(head, int(height), int(width), source.patch_size, "a window")
    except ValueError as exc:
        raise UsageError(f"{exc} ({_where(origin, source.kind)})") from None


def _check_foreign(source: ModelSource, palette: Any, window: Any, statistics: Any) -> None:
    """An ONNX file exported elsewhere needs the palette, window and statistics it records
    nowhere; ``statistics`` is for such a file only, and a known name.

    Raises:
        UsageError: what is missing, or a ``statistics`` given where it does not belong.
    """
    foreign = source.kind == "onnx" and getattr(source.model, "metadata", None) is None
    if foreign:
        given = (("palette", palette), ("window", window), ("statistics", statistics))
        missing = [f"--{n}" for n, v in given if v is None]
        if missing:
            listed = ", ".join(missing[:-1]) + (" and " if len(missing) > 1 else "") + missing[-1]
            raise UsageError(
                f"{source.path} carries no claravid metadata (exported elsewhere): pass "
                f"{listed} to say how to run it (--statistics: "
                f"{' or '.join(NAMED_STATISTICS)}, the statistics its backbone was trained with)"
            )
    if statistics is not None and not foreign:
        raise UsageError(
            f"--statistics is for an ONNX file exported elsewhere: {source.path} records the "
            f"statistics its model was trained with; drop --statistics"
        )
    if statistics is not None and statistics not in NAMED_STATISTICS:
        raise UsageError(
            f"unknown --statistics {statistics!r}: use {' or '.join(NAMED_STATISTICS)}"
        )


def _where(origin: str, kind: str) -> str:
    """Where a window came from, as the error about it says."""
    return {
        "flag": "--window",
        "default": "the default window",
    }.get(origin, f"the window the {kind} records; pass --window to choose another")


def load_source(
    checkpoint: str | Path | None = None,
    onnx: str | Path | None = None,
    *,
    device: torch.device | str = "cpu",
    threads: int | None = None,
    provider: str | None = None,
) -> ModelSource:
    """Load exactly one of ``checkpoint`` / ``onnx``.

    Args:
        checkpoint: A PyTorch checkpoint.
        onnx: An ONNX file.
        device: Where a checkpoint runs (and, for ONNX without ``provider``, CUDA or CPU).
        threads: ONNX Runtime intra-op threads.
        provider: ONNX Runtime provider: ``cpu``, ``cuda`` or ``tensorrt`` (default: CUDA
            when ``device`` is CUDA and onnxruntime has it, else CPU).

    Raises:
        FileNotFoundError: the file does not exist.
        models.CheckpointError: the file is not a claravid checkpoint.
    """
    if (checkpoint is None) == (onnx is None):
        raise ValueError("give exactly one of a checkpoint and an ONNX file")
    if checkpoint is not None:
        from claravid.models.checkpoint import model_from_checkpoint, read_checkpoint

        ckpt = read_checkpoint(checkpoint)  # read once: the model and the training config
        defaults = checkpoint_defaults(ckpt)
        model = model_from_checkpoint(ckpt, checkpoint, map_location=device).eval()
        del ckpt  # the model holds its own copy of the weights now
        return ModelSource(
            model, "checkpoint", str(checkpoint), model.num_classes, model.patch_size, defaults
        )
    from claravid.models.export.runtime import OnnxSegmenter, resolve_providers

    device = torch.device(device)
    if provider is None and device.type != "cuda":
        provider = "cpu"
    providers = resolve_providers(provider)  # one line naming what is missing, before loading
    # No checkpoint: an ONNX file is given.
    segmenter = OnnxSegmenter(onnx, providers=providers, threads=threads)  # type: ignore[arg-type]
    defaults = onnx_defaults(segmenter.metadata)
    return ModelSource(
        segmenter, "onnx", str(onnx), segmenter.num_classes, segmenter.patch_size, defaults
    )

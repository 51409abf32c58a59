"""What the types of a training config alone do not rule out: choices, ranges, required keys,
the head's settings, and what the backbone decides (patch-grid sizes, statistics, the weights
file), named by their dotted keys."""

from __future__ import annotations

import math
import os
from typing import Any, NoReturn

from omegaconf import DictConfig, OmegaConf

from claravid.data.transforms import statistics_problem
from claravid.infra.precision import PRECISIONS
from claravid.models.grid import natural_size, nearest_multiples
from claravid.train.config.schema import (
    BUDGET_UNITS,
    CLASS_WEIGHTS,
    DATASETS,
    SAMPLERS,
    SCHEDULES,
    ConfigError,
    to_plain,
)


def _require(ok: bool, key: str, value: Any, rule: str) -> None:
    if not ok:
        _refuse(key, value, rule)


def _refuse(key: str, value: Any, rule: str) -> NoReturn:
    raise ConfigError(f"bad value for {key}: {value!r} ({rule})")


def _check_split(split: DictConfig) -> None:
    """``data.split`` as ``claravid.data.splits.SplitConfig`` checks it, named ``data.split.*``."""
    from claravid.data.splits import SplitConfigError, make_split_config

    values = to_plain(split)
    try:
        make_split_config(values, "data.split.")
    except SplitConfigError as exc:
        raise ConfigError(str(exc)) from None


def check_config(cfg: DictConfig) -> None:
    """Values the types alone do not rule out: choices, ranges, required keys."""
    for key in ("out_dir", "data.root"):
        _require(
            not OmegaConf.is_missing(cfg, key),
            key,
            "???",
            "required: set it in the file or as key=value",
        )
    # Section by section, in one order: the first bad key found is the one reported.
    _check_data(cfg.data)
    _check_train(cfg.train)
    _check_val(cfg.val)
    _check_head(cfg.model)
    _check_augment(cfg.data.augment)


def _check_data(d: DictConfig) -> None:
    _check_split(d.split)
    _require(d.dataset in DATASETS, "data.dataset", d.dataset, f"one of {', '.join(DATASETS)}")
    _require(
        d.val_dataset in DATASETS,
        "data.val_dataset",
        d.val_dataset,
        f"one of {', '.join(DATASETS)}",
    )
    _require(
        d.class_weights in CLASS_WEIGHTS,
        "data.class_weights",
        d.class_weights,
        f"one of {', '.join(CLASS_WEIGHTS)}",
    )
    _require(d.sampler in SAMPLERS, "data.sampler", d.sampler, f"one of {', '.join(SAMPLERS)}")
    _require(d.sampler_bins >= 1, "data.sampler_bins", d.sampler_bins, ">= 1")
    _require(math.isfinite(d.budget) and 0 < d.budget <= 1, "data.budget", d.budget,
             "a fraction in (0, 1]: 0.1 keeps 10 % of the training images")  # fmt: skip
    _require(d.budget_by in BUDGET_UNITS, "data.budget_by", d.budget_by,
             f"one of {', '.join(BUDGET_UNITS)}")  # fmt: skip
    _require(d.num_workers >= 0, "data.num_workers", d.num_workers, ">= 0")
    _require(d.crops_per_frame >= 1, "data.crops_per_frame", d.crops_per_frame, ">= 1")
    _require(d.val_limit is None or d.val_limit >= 1, "data.val_limit", d.val_limit, ">= 1 or null")
    _require(
        d.gsd is None or (math.isfinite(d.gsd) and d.gsd > 0), "data.gsd", d.gsd,
        "metres per pixel > 0, or null",
    )  # fmt: skip


def _check_train(t: DictConfig) -> None:
    _require(
        t.schedule in SCHEDULES, "train.schedule", t.schedule, f"one of {', '.join(SCHEDULES)}"
    )
    _require(t.steps is None or t.steps >= 1, "train.steps", t.steps, ">= 1 or null")
    _require(
        1 <= t.min_steps <= t.max_steps,
        "train.min_steps",
        t.min_steps,
        "1 <= min_steps <= max_steps",
    )
    _require(t.steps_per_frame > 0, "train.steps_per_frame", t.steps_per_frame, "> 0")
    _require(t.batch_size >= 1, "train.batch_size", t.batch_size, ">= 1")
    _require(t.grad_accum >= 1, "train.grad_accum", t.grad_accum, ">= 1")
    for key in ("lr", "backbone_lr"):
        value = t[key]
        _require(math.isfinite(value) and value > 0, f"train.{key}", value, "a positive number")
    _require(t.weight_decay >= 0, "train.weight_decay", t.weight_decay, ">= 0")
    _require(
        len(t.betas) == 2 and all(0 <= b < 1 for b in t.betas),
        "train.betas",
        list(t.betas),
        "two numbers in [0, 1)",
    )
    # YAML reads off, no and false (on, yes, true) as a boolean: "False" here.
    boolean = " (YAML read a boolean)" if t.precision in ("True", "False") else ""
    _require(t.precision in PRECISIONS, "train.precision", t.precision,
             f"one of {', '.join(PRECISIONS)}{boolean}")  # fmt: skip
    _require(t.warmup_steps >= 0, "train.warmup_steps", t.warmup_steps, ">= 0")
    _require(0 <= t.min_lr_ratio <= 1, "train.min_lr_ratio", t.min_lr_ratio, "in [0, 1]")
    _require(t.grad_clip >= 0, "train.grad_clip", t.grad_clip, ">= 0 (0: off)")
    _require(t.threads is None or t.threads >= 1, "train.threads", t.threads, ">= 1 or null")
    _require(t.log_every >= 1, "train.log_every", t.log_every, ">= 1")
    _require(t.checkpoint_every >= 1, "train.checkpoint_every", t.checkpoint_every, ">= 1")
    _require(
        t.device is None or t.device.split(":")[0] in ("cpu", "cuda"),
        "train.device",
        t.device,
        "cpu, cuda, cuda:N or null",
    )


def _check_val(v: DictConfig) -> None:
    _require(v.every >= 0, "val.every", v.every, ">= 0 (0: at the end only)")
    _require(v.window is None or v.window >= 1, "val.window", v.window, ">= 1 or null")
    _require(v.stride is None or v.stride >= 1, "val.stride", v.stride, ">= 1 or null")
    _require(v.bins >= 1, "val.bins", v.bins, ">= 1")
    _require(math.isfinite(v.scale) and 0 < v.scale <= 8, "val.scale", v.scale, "in (0, 8]")
    _require(v.tta_rule in ("dinov3", "mmseg"), "val.tta_rule", v.tta_rule, "dinov3 or mmseg")
    _require(
        v.tta_scales is None or (len(v.tta_scales) > 0 and all(0 < r <= 8 for r in v.tta_scales)),
        "val.tta_scales", v.tta_scales, "ratios in (0, 8], or null",
    )  # fmt: skip
    _require(v.tta_size is None or v.tta_size >= 1, "val.tta_size", v.tta_size, ">= 1 or null")


def _check_augment(a: DictConfig) -> None:
    _require(
        a.crop_height >= 1 and a.crop_width >= 1, "data.augment.crop_height", a.crop_height, ">= 1"
    )
    problem = statistics_problem(a.mean, a.std)  # before any data is read, not at validation
    if problem is not None:
        raise ConfigError(
            f"bad value for data.augment.{problem}; leave data.augment.mean/std unset for the "
            "backbone's statistics"
        )


def _check_head(m: DictConfig) -> None:
    """``model.head`` is a head, and the head settings given are that head's."""
    from claravid.models.heads.specs import HEAD_NAMES, SETTING_DEFAULTS, check_head_settings

    _require(m.head in HEAD_NAMES, "model.head", m.head, f"one of {', '.join(HEAD_NAMES)}")
    settings = {key: m[key] for key in SETTING_DEFAULTS}
    if settings["layers"] is not None:
        settings["layers"] = list(settings["layers"])
    try:
        check_head_settings(m.head, settings, prefix="model.")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def resolve_backbone(cfg: DictConfig) -> None:
    """Fill in, in place, what the config leaves to the backbone, and check what depends on it.

    - ``data.augment.mean``/``std`` left null: the backbone's statistics;
    - ``val.window`` left null: the model's natural size (`natural_size`);
    - ``data.augment.crop_height``/``crop_width`` and ``val.window`` must be multiples of the
      backbone's patch size (its ``model.backbone_kwargs.patch_size`` when overridden);
    - ``model.weights``: licence-gated weights (DINOv3) cannot be ``official`` and must be
      given as a path; a path is recorded absolute (``~`` expanded, symbolic links kept), so
      the checkpoints that record it are evaluated and exported from any folder;
    - ``model.init``: recorded absolute too.

    Raises:
        ConfigError: an unknown backbone, a size off the patch grid (naming the two nearest
            sizes on it), weights that cannot be had.
    """
    from claravid.models.backbones.specs import BACKBONE_NAMES, BACKBONES

    m, a, v = cfg.model, cfg.data.augment, cfg.val
    spec = BACKBONES.get(m.backbone)
    if spec is None:
        _refuse("model.backbone", m.backbone, f"one of {', '.join(BACKBONE_NAMES)}")
    _check_weights(cfg, spec)
    path = _weights_path(m)
    if path is not None and not _names_hub_repo(path):
        m.weights = os.path.abspath(os.path.expanduser(path))
    if m.init is not None:  # recorded absolute, as the weights: the run is read from anywhere
        m.init = os.path.abspath(os.path.expanduser(m.init))
    patch = int(m.backbone_kwargs.get("patch_size", spec.patch_size))
    if a.mean is None:
        a.mean = tuple(spec.mean)
    if a.std is None:
        a.std = tuple(spec.std)
    if v.window is None:
        v.window = natural_size(patch)
    sizes = {"data.augment.crop_height": a.crop_height, "data.augment.crop_width": a.crop_width,
             "val.window": v.window}  # fmt: skip
    for key, value in sizes.items():
        if value % patch:
            small, large = nearest_multiples(value, patch)
            raise ConfigError(
                f"{key}={value} is not a multiple of the patch size {patch} of {m.backbone}: "
                f"use {small} or {large}"
            )
    from claravid.models.heads.specs import HEADS, check_input_size

    if m.head in HEADS:  # an unknown head is named by the head settings' check
        crops = ("data.augment.crop_height/crop_width", a.crop_height, a.crop_width)
        for key, height, width in (crops, ("val.window", v.window, v.window)):
            try:
                check_input_size(m.head, height, width, patch, key)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None


def _check_weights(cfg: DictConfig, spec: Any) -> None:
    """Licence-gated weights (no download URL) must be given as a file: one line saying so."""
    m = cfg.model
    missing = OmegaConf.is_missing(m, "weights")
    if spec.weights.url is not None or not (missing or m.weights == "official"):
        return
    from claravid.models.backbones.specs import DINOV3_REQUEST_URL

    # A shipped config's `weights: ???` leaves the default ("official") in place when merged.
    timm = next((h for h in spec.weights.hub if h.startswith("timm/")), None)
    ungated = f", or timm's ungated copy: model.weights={timm}" if timm else ""
    raise ConfigError(
        f"model.weights: the {spec.family_name} weights of {spec.name} are licence-gated, with "
        f"no official download; request them at {DINOV3_REQUEST_URL} and pass "
        f"model.weights=/path/to/{spec.weights.file}{ungated}"
    )


def _weights_path(m: DictConfig) -> str | None:
    """``model.weights`` when it names a file, a folder or a hub id (not null, ``official`` or
    missing)."""
    if OmegaConf.is_missing(m, "weights") or m.weights in (None, "official"):
        return None
    return str(m.weights)


def _names_hub_repo(weights: str) -> bool:
    """Whether ``weights`` is a hub id (``timm/...``) rather than a path: as the loader reads it,
    an existing path first."""
    from claravid.models.weights.hub import is_hub_id

    return is_hub_id(weights) and not os.path.exists(os.path.expanduser(weights))


def check_weights_file(cfg: DictConfig) -> None:
    """Find the files of ``model.weights`` (a file, a folder holding one, a hub id) as the model
    will, before any data is indexed or cached and before the run folder is written; the
    tensors themselves are read and checked when the model is built.

    Raises:
        ConfigError: one line naming what was given, what is wrong and what to pass instead.
    """
    path = _weights_path(cfg.model)
    if path is None:
        return
    from claravid.models.backbones.specs import BACKBONES
    from claravid.models.weights.loader import WeightsError, locate_weights

    spec = BACKBONES.get(cfg.model.backbone)
    if spec is None:
        return
    try:
        locate_weights(path, spec)
    except FileNotFoundError:
        hub = next((h for h in spec.weights.hub if h.startswith("timm/")), None)
        instead = "" if spec.weights.url is None else ", model.weights=official"
        instead += f", a hub id such as model.weights={hub}" if hub else ""
        raise ConfigError(
            f"model.weights={path}: no such file or folder; pass the path of "
            f"{cfg.model.backbone}'s .pth or .safetensors weights file or of a folder holding "
            f"one{instead} or model.weights=null (a random backbone)"
        ) from None
    except WeightsError as exc:
        raise ConfigError(f"model.weights={path}: {exc}") from None


def statistics_warning(cfg: DictConfig) -> str | None:
    """What to warn about when ``data.augment.mean/std`` differ from the statistics the
    backbone was pre-trained with (only a config that names other ones can: null takes the
    backbone's); None when they agree."""
    from claravid.models.backbones.specs import BACKBONES, IMAGENET_MEAN

    spec = BACKBONES.get(cfg.model.backbone)
    a = cfg.data.augment
    if spec is None or a.mean is None or a.std is None:
        return None
    mean, std = tuple(float(x) for x in a.mean), tuple(float(x) for x in a.std)
    pairs = zip(mean + std, spec.mean + spec.std, strict=True)
    if all(math.isclose(x, y, abs_tol=1e-9) for x, y in pairs):
        return None
    source = "ImageNet" if spec.mean == IMAGENET_MEAN else spec.weights.dataset
    return (
        f"data.augment.mean {_triple(mean)} and std {_triple(std)} are not the statistics "
        f"{spec.name} was pre-trained with ({source}: mean {_triple(spec.mean)}, std "
        f"{_triple(spec.std)}), so its features are off their training distribution; leave "
        "data.augment.mean/std unset to use the backbone's"
    )


def _triple(values: Any) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in values) + ")"


def derive_steps(cfg: DictConfig, num_frames: int) -> int:
    """``train.steps``, or clamp(steps_per_frame × frames, min_steps, max_steps) when null."""
    t = cfg.train
    if t.steps is not None:
        return int(t.steps)
    return int(min(max(round(t.steps_per_frame * num_frames), t.min_steps), t.max_steps))

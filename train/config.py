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

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn, cast

import yaml
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException

from claravid.data.transforms import AugmentConfig, statistics_problem
from claravid.infra.precision import PRECISIONS
from claravid.infra.resources import shipped_file, shipped_names
from claravid.models.grid import natural_size, nearest_multiples

CLASS_WEIGHTS = ("none", "inverse", "median_frequency", "log_inverse")
SCHEDULES = ("poly", "cosine")
DATASETS = ("claravid", "uavid")
SAMPLERS = ("uniform", "complexity_balanced")


class ConfigError(ValueError):
    """A config file, key or value the user has to fix (the message says how)."""


class StatisticsWarning(UserWarning):
    """The config normalises with statistics other than those the backbone was trained with."""


@dataclass
class SplitSettings:
    """How ClaraVid frames are assigned to train/val/test (``claravid.data.splits.SplitConfig``)."""

    block_size: float = 150.0  # metres: whole squares of camera positions go to one split
    fractions: list[float] = field(default_factory=lambda: [0.7, 0.15, 0.15])
    seed: int = 0
    val_missions: list[str] = field(default_factory=list)  # held out whole as val
    test_missions: list[str] = field(default_factory=list)  # held out whole as test


@dataclass
class DataConfig:
    root: str = MISSING  # the training dataset's root (ClaraVid: the mission folders)
    dataset: str = "claravid"  # training set: claravid | uavid
    palette: str = "claravid"  # palette name or YAML path (uavid: the 8 UAVid classes)
    missions: list[str] | None = None  # ClaraVid mission keys; null: all present
    altitude: list[str] | None = None  # low | mid | high; null: all
    direction: list[str] | None = None  # h | v; null: all
    split: SplitSettings = field(default_factory=SplitSettings)
    train_split: str = "train"
    val_split: str = "val"
    val_dataset: str = "claravid"  # claravid | uavid (synthetic-to-real validation)
    val_root: str | None = None  # null: data.root
    val_limit: int | None = None  # validate on the first N images only (null: all)
    # Metres per pixel of the training images, recorded in checkpoints and ONNX files (predict
    # --gsd auto matches rasters to it). null: ClaraVid measures it (depth at the frame centre /
    # fx, median over training frames); other datasets then record none.
    gsd: float | None = None
    label_cache: bool = (
        True  # label codes kept as tiled TIFFs under $CLARAVID_CACHE, read by region
    )
    num_workers: int = 4  # DataLoader processes per rank (0: in the training process)
    crops_per_frame: int = 1  # k random crops from each decoded frame (1: the paper)
    class_weights: str = "none"  # none | inverse | median_frequency | log_inverse
    sampler: str = "uniform"  # uniform | complexity_balanced (equal draws per delentropy bin)
    sampler_bins: int = 3  # delentropy quantile bins of complexity_balanced
    augment: AugmentConfig = field(default_factory=AugmentConfig)


@dataclass
class ModelConfig:
    backbone: str = "dinov2_vitl14"
    weights: str | None = "official"  # a .pth/.safetensors path, "official", or null (random)
    head: str = "dpt"  # dpt (the paper's) | linear (DINOv3's linear protocol) | upernet
    # Head settings; a setting the chosen head does not take is an error (docs/models.md).
    layers: list[int] | None = None  # null: dpt/upernet the backbone's 4 taps, linear the last
    features: int | None = None  # dpt: fusion width; upernet: its width (null: 512)
    out_channels: list[int] | None = None  # dpt only: reassemble widths
    use_cls: bool = False  # dpt: CLS readout; linear: CLS concatenated to each token
    backbone_kwargs: dict[str, Any] = field(default_factory=dict)  # tiny test backbones
    freeze_backbone: bool = True  # the paper's protocol; false trains the backbone too


@dataclass
class TrainConfig:
    steps: int | None = None  # null: clamp(steps_per_frame × frames, min_steps, max_steps)
    steps_per_frame: float = 10.0  # k of the rule above
    min_steps: int = 5000
    max_steps: int = 30000
    batch_size: int = 8  # images (crops) per optimiser step, over all ranks and accumulation
    grad_accum: int = 1  # micro-batches per optimiser step on each rank
    lr: float = 2e-4  # AdamW on the head (DINOv2/Depth-Anything DPT heads use 1e-4 to 5e-4)
    backbone_lr: float = 2e-4  # used only when model.freeze_backbone is false
    weight_decay: float = 0.01
    betas: list[float] = field(default_factory=lambda: [0.9, 0.999])
    warmup_steps: int = 500  # linear warmup from 0, then the decay schedule
    schedule: str = "poly"  # poly | cosine
    poly_power: float = 0.9
    min_lr_ratio: float = 0.0  # the decay ends at lr × min_lr_ratio
    grad_clip: float = 1.0  # max global gradient norm (0: off)
    # auto: bf16 on GPUs that support it, else fp16 + GradScaler, float32 on CPU;
    # bf16 | fp16 (+ GradScaler) on any device; fp32: no autocast (claravid-train --precision)
    precision: str = "auto"
    compile: bool = False  # torch.compile the trained module
    device: str | None = None  # null: cuda when available, else cpu
    threads: int | None = None  # intra-op CPU threads of each process (null: PyTorch's default)
    log_every: int = 10  # steps between metrics.jsonl rows
    checkpoint_every: int = 500  # steps between last.pt writes (and at the end)


@dataclass
class ValConfig:
    every: int = 1000  # steps between validations (and at the end); 0: at the end only
    window: int | None = None  # a patch multiple; null: the model's (630 for /14, 640 for /16)
    stride: int | None = None  # null: two thirds of the window
    scale: float = 0.5  # resize before windowing (the paper reports at half resolution)
    batch_size: int = 4  # windows per forward pass
    bins: int = 3  # delentropy quantile bins of the val images (miou_bins)


@dataclass
class LogConfig:
    tensorboard: bool = (
        False  # event files in out_dir/tb (pip install 'claravid-toolkit[tensorboard]')
    )
    progress: bool = True  # progress bar on rank 0


@dataclass
class Config:
    """Everything a run needs; ``out_dir`` holds its results."""

    out_dir: str = MISSING
    seed: int = 0
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    val: ValConfig = field(default_factory=ValConfig)
    log: LogConfig = field(default_factory=LogConfig)


def valid_keys(node: Any = None, prefix: str = "") -> list[str]:
    """Every dotted key of the schema (free-form dicts such as ``backbone_kwargs`` as one key)."""
    node = OmegaConf.structured(Config) if node is None else node
    keys = []
    for key in node:
        full = f"{prefix}{key}"
        child = node._get_node(key)
        if isinstance(child, DictConfig) and OmegaConf.get_type(child) not in (dict, None):
            keys.extend(valid_keys(child, f"{full}."))
        else:
            keys.append(full)
    return keys


def _unknown_key(full_key: str) -> ConfigError:
    close = difflib.get_close_matches(full_key, valid_keys(), n=3, cutoff=0.6)
    leaf = full_key.rsplit(".", 1)[-1]
    close += [k for k in valid_keys() if k.rsplit(".", 1)[-1] == leaf and k not in close]
    hint = f"; did you mean {' or '.join(close[:3])}?" if close else ""
    return ConfigError(f"unknown config key {full_key!r}{hint}")


def find_config(name: str | Path) -> tuple[Path | None, str]:
    """(path, text) of a config file path or a shipped config name."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise ConfigError(f"config file {path} not found")
        return path, _read_text(path)
    entry = shipped_file(str(name))
    if entry is None:
        raise ConfigError(
            f"no config file {name} and no shipped config named {name!r}; "
            f"shipped: {', '.join(n for n in shipped_names() if n != 'augment')}"
        )
    return None, entry.read_text(encoding="utf-8")


def _read_text(path: Path) -> str:
    """A config file's text; a binary file is refused by name."""
    data = path.read_bytes()
    try:
        if b"\x00" in data:
            raise UnicodeDecodeError("utf-8", data, data.index(b"\x00"), len(data), "NUL byte")
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"config {path} is not a YAML text file (binary data at byte {exc.start}); "
            "pass a .yaml file or a shipped config name"
        ) from None


def _check_loaded(loaded: Any, source: str) -> DictConfig:
    """The file is a mapping of sections, each section a mapping (as the schema has it): the
    file's config, checked."""
    if not isinstance(loaded, DictConfig):
        kind = "a list" if isinstance(loaded, ListConfig) else "no mapping"
        raise ConfigError(
            f"{source} holds {kind}, not a mapping of sections (out_dir:, data:, model:, "
            "train:, val:, log:)"
        )
    schema = OmegaConf.structured(Config)
    for key in loaded:
        section = str(key)
        node = schema._get_node(section) if section in schema else None
        value = loaded._get_node(key)
        if isinstance(node, DictConfig) and not isinstance(value, DictConfig):
            got = to_plain(loaded, resolve=False)[section]
            raise ConfigError(
                f"{source}: section {section} must be a mapping of keys, e.g. "
                f"{section}: {{{next(iter(node))!s}: ...}}; got {got!r}"
            )
    return loaded


def _merge(base: DictConfig, other: Any, source: str) -> DictConfig:
    try:
        merged = OmegaConf.merge(base, other)
    except ConfigKeyError as exc:
        raise _unknown_key(str(exc.full_key)) from None
    except OmegaConfBaseException as exc:
        key = getattr(exc, "full_key", None)
        msg = str(exc).splitlines()[0]
        raise ConfigError(f"bad value for {key} ({source}): {msg}") from None
    return merged  # type: ignore[return-value]  # a structured config merges into a DictConfig


def load_config(name: str | Path, overrides: list[str] | tuple[str, ...] | str = ()) -> DictConfig:
    """Defaults, then the YAML file (path or shipped name), then ``key=value`` overrides.

    ``overrides`` is a list of ``key=value`` strings, or one string of them separated by spaces.

    Raises:
        ConfigError: unknown key, bad value, missing required key, unreadable file, a file
            that is not a mapping of sections (a list, a single value, binary data).
    """
    cfg = OmegaConf.structured(Config)
    path, text = find_config(name)
    source = f"config {path or name}"
    try:
        loaded = OmegaConf.create(text) if text.strip() else OmegaConf.create({})
    except Exception as exc:  # a YAML syntax error, or a bare scalar: name the file
        if not isinstance(_safe_load(text), (dict, list)):
            raise ConfigError(
                f"{source} holds a single value, not a mapping of sections (out_dir:, data:, "
                "model:, train:, val:, log:)"
            ) from None
        raise ConfigError(f"cannot parse {source}: {exc}") from None
    sections = _check_loaded(loaded, source)
    _check_statistics_given(sections, source)
    _one_item_lists(cfg, sections)
    cfg = _merge(cfg, sections, source)
    if isinstance(overrides, str):  # "train.steps=5 val.every=0": one string, split on spaces
        overrides = overrides.split()
    bad = [o for o in overrides if "=" not in o or o.startswith("=")]
    if bad:
        raise ConfigError(f"override {bad[0]!r} is not key=value (e.g. train.steps=100)")
    given = OmegaConf.from_dotlist(list(overrides))
    _check_statistics_given(given, "command line")
    _one_item_lists(cfg, given)
    cfg = _merge(cfg, given, "command line")
    check_config(cfg)
    resolve_backbone(cfg)
    return cfg


def _check_statistics_given(given: DictConfig, source: str) -> None:
    """``data.augment.mean/std`` as given must be three numbers each (or null): said here, by
    key, instead of OmegaConf's "bad value for None ... '$VALUE'" from the merge."""
    augment = given.get("data", {}).get("augment", {}) if "data" in given else {}
    if not isinstance(augment, DictConfig):
        return  # not a mapping: _check_loaded and the merge name it
    for name in ("mean", "std"):
        if name not in augment:
            continue
        container = OmegaConf.to_container(augment, resolve=False)
        if not isinstance(container, dict):  # a DictConfig always converts to a dict
            raise TypeError(f"data.augment converted to a {type(container).__name__}, not a dict")
        value = container[name]
        if value is None or _three_numbers(value):
            continue  # the merge converts them; check_config checks their values
        problem = statistics_problem(value if name == "mean" else None,
                                     value if name == "std" else None)  # fmt: skip
        raise ConfigError(f"bad value for data.augment.{problem} ({source})")


def _three_numbers(value: Any) -> bool:
    if (
        not isinstance(value, list | tuple)
        or len(value) != 3
        or any(isinstance(v, bool) for v in value)
    ):
        return False
    try:
        [float(v) for v in value]
    except (TypeError, ValueError):
        return False
    return True


def _one_item_lists(schema: DictConfig, given: DictConfig) -> None:
    """A single value where the schema has a list is a list of one, in place
    (``data.split.test_missions=urban_high_1``, as ``SplitConfig`` takes a single string)."""
    for key in list(given.keys()):
        if key not in schema:
            continue  # an unknown key: _merge names it
        node, value = schema._get_node(str(key)), given._get_node(key)
        if isinstance(node, DictConfig) and isinstance(value, DictConfig):
            _one_item_lists(node, value)
        elif isinstance(node, ListConfig) and not isinstance(value, (ListConfig, DictConfig)):
            item = given[key]
            if item is not None:
                given[key] = [item]


def _safe_load(text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return {}  # a syntax error: reported as such by the caller


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
    d, t, v, m = cfg.data, cfg.train, cfg.val, cfg.model
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
    _require(d.num_workers >= 0, "data.num_workers", d.num_workers, ">= 0")
    _require(d.crops_per_frame >= 1, "data.crops_per_frame", d.crops_per_frame, ">= 1")
    _require(d.val_limit is None or d.val_limit >= 1, "data.val_limit", d.val_limit, ">= 1 or null")
    _require(
        d.gsd is None or (math.isfinite(d.gsd) and d.gsd > 0), "data.gsd", d.gsd,
        "metres per pixel > 0, or null",
    )  # fmt: skip
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
    _require(v.every >= 0, "val.every", v.every, ">= 0 (0: at the end only)")
    _require(v.window is None or v.window >= 1, "val.window", v.window, ">= 1 or null")
    _require(v.stride is None or v.stride >= 1, "val.stride", v.stride, ">= 1 or null")
    _require(v.bins >= 1, "val.bins", v.bins, ">= 1")
    _require(math.isfinite(v.scale) and 0 < v.scale <= 8, "val.scale", v.scale, "in (0, 8]")
    _check_head(m)
    a = d.augment
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
      the checkpoints that record it are evaluated and exported from any folder.

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
    if _weights_path(m) is not None:
        m.weights = os.path.abspath(os.path.expanduser(m.weights))
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
    """``model.weights`` when it names a file (not null, ``official`` or missing)."""
    if OmegaConf.is_missing(m, "weights") or m.weights in (None, "official"):
        return None
    return str(m.weights)


def check_weights_file(cfg: DictConfig) -> None:
    """Refuse a ``model.weights`` path that is no file, before any data is indexed or cached
    and before the run folder is written.

    Raises:
        ConfigError: one line naming the path and what to pass instead.
    """
    path = _weights_path(cfg.model)
    if path is None or os.path.isfile(path):
        return
    from claravid.models.backbones.specs import BACKBONES

    spec = BACKBONES.get(cfg.model.backbone)
    what = "a folder, not a file" if os.path.isdir(path) else "no such file"
    instead = "" if spec is None or spec.weights.url is None else ", model.weights=official"
    raise ConfigError(
        f"model.weights={path}: {what}; pass the path of {cfg.model.backbone}'s .pth or "
        f".safetensors weights file{instead} or model.weights=null (a random backbone)"
    )


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


def to_yaml(cfg: DictConfig) -> str:
    """The resolved config as YAML (what ``out_dir/config.yaml`` holds)."""
    return OmegaConf.to_yaml(cfg)


def to_plain(cfg: DictConfig, resolve: bool = True) -> dict[str, Any]:
    """Plain dict/list/str/number container (storable in a ``weights_only`` checkpoint); the keys
    of a config's sections are strings."""
    return cast(dict[str, Any], OmegaConf.to_container(cfg, resolve=resolve))


def from_plain(data: dict[str, Any]) -> DictConfig:
    """A config back from `to_plain` (a checkpoint's), checked against the schema."""
    return _merge(OmegaConf.structured(Config), data, "checkpoint")


#: Keys a resumed run may change: where things are and how they are shown, not what is learnt.
RESUMABLE_CHANGES = (
    "out_dir",  # a run folder moved or copied elsewhere resumes from where it is now
    "data.root",
    "data.val_root",
    "data.num_workers",
    "log.",
    "train.device",
    "train.threads",
)


def changed_keys(old: DictConfig, new: DictConfig) -> list[str]:
    """Dotted keys whose values differ between two configs (ignoring `RESUMABLE_CHANGES`)."""
    flat_old, flat_new = _flatten(to_plain(old)), _flatten(to_plain(new))
    keys = sorted(set(flat_old) | set(flat_new))
    return [
        k
        for k in keys
        if flat_old.get(k) != flat_new.get(k)
        and not any(k == p or (p.endswith(".") and k.startswith(p)) for p in RESUMABLE_CHANGES)
    ]


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: list(data) if isinstance(data, tuple) else data}

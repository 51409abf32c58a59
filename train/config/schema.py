"""What a training config holds: its sections as typed defaults (OmegaConf structured configs),
the choices they take, its errors, and its plain forms (the YAML of ``out_dir/config.yaml``, the
dict a checkpoint stores, which keys differ between two configs)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

from omegaconf import MISSING, DictConfig, OmegaConf

from claravid.data.transforms import AugmentConfig

CLASS_WEIGHTS = ("none", "inverse", "median_frequency", "log_inverse")
SCHEDULES = ("poly", "cosine")
DATASETS = ("claravid", "uavid", "udd5", "udd6", "vdd", "aeroscapes", "icg")
SAMPLERS = ("uniform", "complexity_balanced")
#: What ``data.budget_by`` accepts (`claravid.train.budget`): ``auto`` is the dataset's unit.
BUDGET_UNITS = ("auto", "sequence", "block", "pass", "mission", "folder")


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
    val_dataset: str = "claravid"  # claravid | uavid | udd5 | udd6 | vdd | aeroscapes | icg
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
    # Label budget (docs/training.md): the share of the training split's labelled images kept,
    # drawn as whole units (auto: UAVid sequences, ClaraVid blocks), nested for one seed.
    budget: float = 1.0  # in (0, 1]: 0.01, 0.05, 0.1, 0.25, 1.0 for a label-budget curve
    budget_by: str = "auto"  # auto | sequence | block | pass | mission | folder
    budget_seed: int = 0  # the draw's seed, apart from `seed`: one subset, several trainings
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
    # Another run's checkpoint (best.pt) whose head (and stored backbone) starts this run; a
    # fresh optimiser and step 0, not a resume. Same backbone and class names required.
    init: str | None = None


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
    # Test-time augmentation (docs/evaluation.md): the ratios of the copies (null: none), the
    # mirror, the copy-size rule (dinov3 or mmseg) and the dinov3 rule's S (null: the image's
    # small side at val.scale). Recorded in the checkpoint and the ONNX metadata.
    tta_scales: list[float] | None = None
    tta_flip: bool = False
    tta_rule: str = "dinov3"
    tta_size: int | None = None


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


def to_yaml(cfg: DictConfig) -> str:
    """The resolved config as YAML (what ``out_dir/config.yaml`` holds)."""
    return OmegaConf.to_yaml(cfg)


def to_plain(cfg: DictConfig, resolve: bool = True) -> dict[str, Any]:
    """Plain dict/list/str/number container (storable in a ``weights_only`` checkpoint); the keys
    of a config's sections are strings."""
    return cast(dict[str, Any], OmegaConf.to_container(cfg, resolve=resolve))


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

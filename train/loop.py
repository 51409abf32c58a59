"""The training loop: config → data and model → steps → checkpoints, validation, logs.

::

    claravid-train --config demo                                  # one process
    torchrun --nproc_per_node=8 -m claravid.train --config claravid_dpt_vitl14 \
        --data /data/claravid

One optimiser step takes ``train.batch_size`` crops over all ranks and ``train.grad_accum``
micro-batches; its loss is the mean of the micro-batches' losses (each the pixel mean of
weighted cross-entropy over non-ignored pixels), so W ranks × A micro-batches compute the same
gradient as one process with W·A micro-batches. Precision (``train.precision``): ``auto`` is
bf16 autocast where the GPU supports it, else fp16 with a GradScaler, float32 on CPU; ``bf16``
and ``fp16`` (with a GradScaler) autocast on any device, CPU included; ``fp32`` is float32.
Validation runs at the training precision. A NaN/inf loss stops the run before the step is
applied.

:func:`train` reads in one sitting: :func:`build_run` (data, model, optimiser, resumed state),
then per step :func:`optimiser_step` and :func:`after_step` (log row, validation, checkpoints).
"""

from __future__ import annotations

import contextlib
import json
import math
import random
import shlex
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from omegaconf import DictConfig
from torch import nn
from tqdm.auto import tqdm

from claravid import models
from claravid.data.gsd import claravid_gsd, gsd_record
from claravid.data.ignore import IGNORE_INDEX
from claravid.data.masks import check_palette_fit
from claravid.data.palettes import load_palette
from claravid.data.real_layouts import RealSegmentation
from claravid.data.samples import normalise
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.targets import UAVidSegmentation
from claravid.eval.inference.augment import TTAConfig
from claravid.eval.inference.windows import WindowConfig
from claravid.infra.cli import check_device
from claravid.infra.distributed import DistInfo, barrier, init_distributed
from claravid.infra.files import atomic_write_text
from claravid.infra.precision import autocast_dtype, precision_name
from claravid.io import jpeg_region
from claravid.train import config as C
from claravid.train.budget import Budget, apply_budget, draw_budget
from claravid.train.checkpoint import (
    load_training_checkpoint,
    restore_model,
    save_training_checkpoint,
    set_rng_state,
)
from claravid.train.data import (
    build_train_dataset,
    build_train_loader,
    build_val_dataset,
    check_batch,
    class_frequencies,
    class_weights,
    image_paths,
    prepare_label_caches,
    split_table,
)
from claravid.train.init import apply_init, init_record, read_init
from claravid.train.logs import RunLog, plot_curves, read_metrics
from claravid.train.optim import build_optimizer, build_scheduler, clip_gradients
from claravid.train.outdir import prepare_out_dir
from claravid.train.sampler import complexity_groups
from claravid.train.validate import Validator


class TrainingDiverged(RuntimeError):
    """The loss became NaN or infinite; the last good checkpoint is kept."""


@dataclass
class RunResult:
    """Where a run ended: its folder, step, best validation score and last validation row."""

    out_dir: Path
    step: int
    total_steps: int
    best_miou: float | None = None
    best_step: int | None = None
    last_val: dict[str, Any] = field(default_factory=dict)
    already_finished: bool = False


def segmentation_loss(
    logits: torch.Tensor, target: torch.Tensor, weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Cross-entropy in float32, (weighted) mean over the pixels whose train id is not
    ``IGNORE_INDEX``: a crop's padding and the classes a palette ignores never train."""
    return F.cross_entropy(logits.float(), target, weight=weights, ignore_index=IGNORE_INDEX)


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002  (the legacy global RNG, for libraries that use it)
    torch.manual_seed(seed)


def _global_mean(value: torch.Tensor, info: DistInfo) -> float:
    """The mean of a scalar over ranks (every rank gets it, so all stop together on NaN)."""
    if info.world_size > 1:
        value = value.detach().clone()
        dist.all_reduce(value)
        value /= info.world_size
    return float(value)


def _finite_parameters(model: nn.Module) -> bool:
    return all(bool(torch.isfinite(p).all()) for p in model.parameters() if p.requires_grad)


@dataclass
class Run:
    """Everything one training run holds between steps (:func:`build_run` makes it)."""

    cfg: DictConfig
    info: DistInfo
    out: Path
    start: int
    total: int
    model: models.Segmenter
    module: nn.Module  # what the steps call: the model, under DDP, compiled
    ddp: nn.parallel.DistributedDataParallel | None
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    scaler: torch.amp.GradScaler
    dtype: torch.dtype | None
    weights: torch.Tensor | None
    validator: Validator
    batches: Any  # the training loader's iterator
    log: RunLog | None
    frames_per_step: int
    say: Any
    best_miou: float | None = None
    best_step: int | None = None
    last_val: dict[str, Any] = field(default_factory=dict)
    # What every checkpoint records beside the weights: classes, label budget, init source.
    records: dict[str, Any] = field(default_factory=dict)
    store_backbone: bool = False  # a trained backbone, or one loaded by model.init
    gsd: dict[str, Any] | None = None  # the training images' GSD record (claravid.data.gsd)
    images: int = 0  # images since the last log row (for images/s)
    tick: float = 0.0  # when the last log row was written

    @property
    def normalisation(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The crops' ``(mean, std)``, applied on the device: ``data.augment``'s, which the
        resolved config holds (the backbone's unless the config names others)."""
        augment = self.cfg.data.augment
        return tuple(augment.mean), tuple(augment.std)

    def checkpoint(self, path: Path, step: int) -> None:
        """Write a training checkpoint of the run as it is after ``step`` steps."""
        save_training_checkpoint(
            path, self.model, step=step, config=C.to_plain(self.cfg), optimizer=self.optimizer,
            scheduler=self.scheduler, scaler=self.scaler, frames_per_step=self.frames_per_step,
            best_miou=self.best_miou, best_step=self.best_step, metrics=self.last_val,
            backbone_trained=self.store_backbone, gsd=self.gsd, **self.records,
        )  # fmt: skip


def train(
    cfg: DictConfig, *, resume: bool = False, say: Callable[[str], object] = print
) -> RunResult:
    """Run (or resume) the training a resolved config describes; rank 0 writes ``out_dir``.

    Args:
        cfg: from `claravid.train.config.load_config`.
        resume: continue from ``out_dir/last.pt`` (a fresh start when there is none).
        say: where rank 0's messages go.

    Raises:
        TrainingDiverged: a NaN/inf loss (``last.pt`` holds the last good state).
        ValueError, FileNotFoundError: a user's mistake (config, data, out_dir).
    """
    run = build_run(cfg, resume, say)
    if isinstance(run, RunResult):
        return run
    main = run.info.is_main
    bar = tqdm(total=run.total, initial=run.start, unit="step",
               disable=not (main and cfg.log.progress), dynamic_ncols=True)  # fmt: skip
    run.tick = time.perf_counter()
    try:
        for step in range(run.start, run.total):
            lr = float(run.scheduler.get_last_lr()[-1])
            loss, grad_norm = optimiser_step(run, step, lr)
            after_step(run, step + 1, loss, lr, grad_norm, bar)
    finally:
        bar.close()
        if run.log is not None:
            run.log.close()
            rows = read_metrics(run.log.path)
            if rows:
                plot_curves(rows, run.out / "curves.png")
    return RunResult(run.out, run.total, run.total, run.best_miou, run.best_step, run.last_val)


def build_run(
    cfg: DictConfig, resume: bool, say: Callable[[str], object] = print
) -> Run | RunResult:
    """Data, model, optimiser, checkpoint state and logs of a run, ready for its first step.

    Returns a :class:`RunResult` instead when ``out_dir`` holds a finished run (nothing to do).
    """
    C.resolve_backbone(cfg)  # idempotent: a config not from load_config gets it too
    C.check_weights_file(cfg)  # before indexing, the label cache and config.yaml
    init = _init_source(cfg, resume)  # likewise: a refused model.init writes nothing
    info, say = _start_process(cfg, say)
    device, main = info.device, info.is_main
    if main and (message := C.statistics_warning(cfg)) is not None:
        warnings.warn(message, C.StatisticsWarning, stacklevel=2)  # once: rank 0, at start
    frames_per_step = check_batch(cfg, info.world_size)
    train_set = _training_data(cfg)
    budget = _label_budget(cfg, train_set)
    cfg.train.steps = C.derive_steps(cfg, len(train_set))  # resolved: stored in config.yaml
    total = int(cfg.train.steps)
    out, ckpt = _claim_out_dir(cfg, resume, info, say)
    start = int(ckpt["step"]) if ckpt else 0
    if ckpt is not None and start >= total:  # total >= 1: only a checkpoint gets there
        return _finished(out, ckpt, start, total, say)
    if main and budget.units is not None:  # a draw (below 1.0): said, and its keys written
        _record_budget(out, budget, say)
    val_set, palette = _validation_data(cfg, train_set, say)
    if info.is_main:  # one process builds the label cache; the others wait and then read it
        prepare_label_caches([train_set, val_set], cfg.data.num_workers, say)
        say(f"RGB crops: {jpeg_region.decoder()}")
    barrier()
    model = _build_model(cfg, palette.num_classes)
    from_init = init is not None and ckpt is None and _start_from(model, cfg, init, say)
    dtype = autocast_dtype(cfg.train.precision, device)
    # Checked before the first step, not at the first validation.
    window = _val_window(cfg, model.patch_size, precision_name(dtype))
    if not cfg.model.freeze_backbone:
        model.unfreeze_backbone()  # before the optimiser collects what trains
    model.to(device)
    optimizer = build_optimizer(model, cfg)
    scheduler = build_scheduler(optimizer, cfg, total)
    # fp16 overflows without loss scaling; bf16 has float32's range and needs none.
    scaler = torch.amp.GradScaler(device.type, enabled=dtype == torch.float16)
    say(
        f"precision: {precision_name(dtype)} (train.precision={cfg.train.precision}, {device.type})"
    )
    weights = _class_weights(cfg, train_set, palette.num_classes, info)
    best_miou, best_step = None, None
    last_val: dict[str, Any] = {}
    if ckpt:
        restore_model(model, ckpt)
        optimizer.load_state_dict(ckpt["optimizer"])
        scheduler.load_state_dict(ckpt["scheduler"])
        if ckpt.get("scaler"):
            scaler.load_state_dict(ckpt["scaler"])
        best_miou, best_step = ckpt.get("best_miou"), ckpt.get("best_step")
        last_val = ckpt.get("metrics") or {}
        say(f"resuming {out / 'last.pt'} at step {start}/{total}")
    module, ddp = _wrap(model, cfg, info)
    validator = Validator(val_set, list(palette.names), window, cfg.val.bins, cfg.data.val_limit,
                          device)  # fmt: skip
    batches = _batches(cfg, train_set, info, start)
    if ckpt:  # after the loader drew its base seed from the torch RNG
        set_rng_state(ckpt["rng"])
    if ckpt:  # a resumed run keeps what its first start recorded of model.init
        started_from = ckpt.get("init")
    else:
        started_from = init_record(init, cfg.model.init) if init is not None else None
    records = {"classes": list(palette.names), "budget": budget.record(), "init": started_from}
    store = (
        not cfg.model.freeze_backbone or from_init or bool(ckpt and ckpt.get("backbone_included"))
    )
    return Run(
        cfg=cfg, info=info, out=out, start=start, total=total, model=model, module=module,
        ddp=ddp, optimizer=optimizer, scheduler=scheduler, scaler=scaler, dtype=dtype,
        weights=weights, validator=validator, batches=batches,
        log=RunLog(out, start, cfg.log.tensorboard) if main else None,
        frames_per_step=frames_per_step, say=say, best_miou=best_miou, best_step=best_step,
        last_val=last_val, records=records, store_backbone=store,
        gsd=ckpt.get("gsd") if ckpt else training_gsd(cfg, train_set),
    )  # fmt: skip


def _start_process(cfg: DictConfig, say: Any) -> tuple[DistInfo, Any]:
    """Device, process group, threads and seeds; only rank 0 speaks."""
    check_device(cfg.train.device, "train.device")  # one line, not CUDA's traceback
    info = init_distributed(cfg.train.device)
    torch.backends.cudnn.benchmark = info.device.type == "cuda"
    if cfg.train.threads:
        torch.set_num_threads(cfg.train.threads)
    _seed_everything(cfg.seed)
    return info, say if info.is_main else (lambda *a, **k: None)


def _training_data(cfg: DictConfig) -> Any:
    """The training split, its UAVid labels checked against ``data.palette``."""
    train_set = build_train_dataset(cfg)
    if isinstance(train_set, UAVidSegmentation):  # label files in a palette: the right one?
        check_palette_fit([train_set.label_path(p) for p in train_set.images],
                          load_palette(cfg.data.palette), "data.palette", "uavid")  # fmt: skip
    if isinstance(train_set, RealSegmentation):  # ids or colours of the dataset named?
        check_palette_fit(train_set.masks, train_set.palette, "data.palette", train_set.dataset)
    return train_set


def _label_budget(cfg: DictConfig, train_set: Any) -> Budget:
    """Cut the training split to its label budget (``data.budget``), in place; the draw."""
    d = cfg.data
    budget = draw_budget(train_set, d.budget, d.budget_by, d.budget_seed)
    apply_budget(train_set, budget)
    return budget


def _record_budget(out: Path, budget: Budget, say: Any) -> None:
    """The label budget in the log, and in ``out_dir/budget.json`` with the kept images' keys."""
    say(budget.line())
    atomic_write_text(out / "budget.json", json.dumps(budget.record(keys=True), indent=1) + "\n")


def _init_source(cfg: DictConfig, resume: bool) -> dict[str, Any] | None:
    """The checkpoint ``model.init`` names, checked against this run (None: no model.init,
    or a resume, which continues from ``last.pt`` instead)."""
    m = cfg.model
    if m.init is None or (resume and (Path(cfg.out_dir) / "last.pt").is_file()):
        return None
    classes = list(load_palette(cfg.data.palette).names)
    return read_init(m.init, m.backbone, dict(m.backbone_kwargs), m.weights, m.head, classes)


def _start_from(model: models.Segmenter, cfg: DictConfig, init: dict[str, Any], say: Any) -> bool:
    """Load ``model.init``'s head (and stored backbone); whether the backbone came too."""
    loaded = apply_init(model, init, cfg.model.init)
    what = "head and backbone" if loaded else "head"
    say(f"model.init: {what} from {cfg.model.init} (step {init.get('step')} of that run); "
        "a fresh optimiser from step 0")  # fmt: skip
    return loaded


def training_gsd(cfg: DictConfig, train_set: Any) -> dict[str, Any] | None:
    """The GSD record a run's checkpoints carry: ``data.gsd`` when stated, else ClaraVid's
    measured one (``claravid.data.gsd``), else None."""
    if cfg.data.gsd is not None:
        return gsd_record(float(cfg.data.gsd), "data.gsd")
    if isinstance(train_set, ClaraVidSegmentation):
        return claravid_gsd(train_set.root, train_set.frames)
    return None


def _claim_out_dir(
    cfg: DictConfig, resume: bool, info: DistInfo, say: Any
) -> tuple[Path, dict[str, Any] | None]:
    """Rank 0 checks and claims ``out_dir``; the others then read the same checkpoint."""
    out = Path(cfg.out_dir)
    ckpt = prepare_out_dir(out, cfg, resume, say=say) if info.is_main else None
    barrier()
    if not info.is_main and resume and (out / "last.pt").is_file():
        ckpt = load_training_checkpoint(out / "last.pt")
    return out, ckpt


def _finished(out: Path, ckpt: dict[str, Any], start: int, total: int, say: Any) -> RunResult:
    say(f"{out}: this run is already finished (step {start}/{total}); nothing to do")
    if (ckpt.get("metrics") or {}).get("step") != start:
        say(f"its final validation did not complete: claravid-eval --checkpoint "
            f"{shlex.quote(str(out / 'last.pt'))} evaluates it")  # fmt: skip
    return RunResult(out, start, total, ckpt.get("best_miou"), ckpt.get("best_step"),
                     ckpt.get("metrics") or {}, already_finished=True)  # fmt: skip


def _validation_data(cfg: DictConfig, train_set: Any, say: Any) -> tuple[Any, Any]:
    """The validation split and the palette, the split's balance said once."""
    val_set = build_val_dataset(cfg)
    if (shares := split_table(train_set)) is not None:
        say(shares)
    palette = load_palette(cfg.data.palette)
    if isinstance(val_set, UAVidSegmentation):  # UAVid val labels in data.palette: right one?
        check_palette_fit([val_set.label_path(p) for p in val_set.images], palette,
                          "data.palette", "uavid")  # fmt: skip
    if isinstance(val_set, RealSegmentation):  # ids or colours of the dataset named?
        check_palette_fit(val_set.masks, palette, "data.palette", val_set.dataset)
    return val_set, palette


def _build_model(cfg: DictConfig, num_classes: int) -> models.Segmenter:
    m = cfg.model
    return models.build_model(
        m.backbone,
        num_classes=num_classes,
        weights=m.weights,
        head=m.head,
        layers=list(m.layers) if m.layers is not None else None,
        features=m.features,
        out_channels=list(m.out_channels) if m.out_channels is not None else None,
        use_cls=m.use_cls,
        backbone_kwargs=dict(m.backbone_kwargs),
    )


def _class_weights(
    cfg: DictConfig, train_set: Any, num_classes: int, info: DistInfo
) -> torch.Tensor | None:
    if cfg.data.class_weights == "none":
        return None
    # Counting decodes every label file of the split; the counts are cached on disk: rank 0
    # counts, the others then read the cache.
    if info.is_main:
        counts = class_frequencies(train_set, num_classes)
    barrier()
    if not info.is_main:
        counts = class_frequencies(train_set, num_classes)
    # None only for `none`, returned above.
    return class_weights(counts, cfg.data.class_weights).to(info.device)  # type: ignore[union-attr]


def _wrap(
    model: models.Segmenter, cfg: DictConfig, info: DistInfo
) -> tuple[nn.Module, nn.parallel.DistributedDataParallel | None]:
    """What the steps call: the model under DDP (several ranks) and compiled (train.compile)."""
    module: nn.Module = model
    ddp = None
    if info.world_size > 1:
        ids = [info.device.index] if info.device.type == "cuda" else None
        if info.device.type == "cuda":
            # The heads' BatchNorms (linear, UperNet) normalise over every rank's micro-batch, as
            # the official protocols train them. SyncBatchNorm needs CUDA; it keeps the module's
            # parameters (the optimiser's) and state-dict keys.
            model = nn.SyncBatchNorm.convert_sync_batchnorm(model)
        module = ddp = nn.parallel.DistributedDataParallel(model, device_ids=ids)
    if cfg.train.compile:
        # A compiled Module is a Module (OptimizedModule); torch's stubs say a callable.
        module = torch.compile(module)  # type: ignore[assignment]
    module.train()
    return module, ddp


def _batches(cfg: DictConfig, train_set: Any, info: DistInfo, start: int) -> Any:
    """The training loader's iterator from step ``start`` (complexity-balanced if asked)."""
    groups = None
    if cfg.data.sampler == "complexity_balanced":
        groups = complexity_groups(image_paths(train_set), cfg.data.sampler_bins)
    loader = build_train_loader(
        train_set, cfg, rank=info.rank, world_size=info.world_size, start_step=start,
        pin_memory=info.device.type == "cuda", groups=groups,
    )  # fmt: skip
    return iter(loader)  # draws the loader's base seed from the torch RNG


def optimiser_step(run: Run, step: int, lr: float) -> tuple[float, float]:
    """One optimiser step over ``train.grad_accum`` micro-batches: (mean loss, gradient norm).

    Raises:
        TrainingDiverged: the loss is NaN/inf (the step is not applied).
    """
    device, dtype, accum = run.info.device, run.dtype, run.cfg.train.grad_accum
    run.optimizer.zero_grad(set_to_none=True)
    losses = []
    for micro in range(accum):
        batch = next(run.batches)
        # uint8 crops until here: normalised and widened on the device, not in the workers.
        x = normalise(batch["image"].to(device, non_blocking=True), *run.normalisation)
        y = batch["mask"].to(device, non_blocking=True).long()
        # Gradients are all-reduced once per step, on the last micro-batch.
        last = micro == accum - 1
        with contextlib.nullcontext() if run.ddp is None or last else run.ddp.no_sync():
            with torch.autocast(device.type, dtype=dtype, enabled=dtype is not None):
                logits = run.module(x)
            loss = segmentation_loss(logits, y, run.weights)
            run.scaler.scale(loss / accum).backward()
        losses.append(loss.detach())
        run.images += x.shape[0]
    loss_value = _global_mean(torch.stack(losses).mean(), run.info)
    if not math.isfinite(loss_value):
        raise TrainingDiverged(
            f"the loss became {loss_value} at step {step + 1} (lr {lr:.3g}); that step "
            f"is not applied. {_last_good(run.out)} Lower train.lr, keep "
            "train.grad_clip on, or check the data, then start a new out_dir or --resume."
        )
    run.scaler.unscale_(run.optimizer)
    grad_norm = clip_gradients(run.model, run.cfg.train.grad_clip)
    run.scaler.step(run.optimizer)
    run.scaler.update()
    run.scheduler.step()
    return loss_value, grad_norm


def after_step(run: Run, done: int, loss: float, lr: float, grad_norm: float, bar: Any) -> None:
    """What follows step ``done``: the log row, validation (and ``best.pt``), ``last.pt``."""
    cfg, main, out = run.cfg, run.info.is_main, run.out
    if run.log is not None and (done % cfg.train.log_every == 0 or done == run.total):
        now = time.perf_counter()
        rate = run.images * run.info.world_size / max(now - run.tick, 1e-9)
        run.tick, run.images = now, 0
        run.log.write({"step": done, "loss": loss, "lr": lr, "images_per_s": rate,
                       "grad_norm": grad_norm})  # fmt: skip
        bar.set_postfix(loss=f"{loss:.4f}", lr=f"{lr:.2e}", img_s=f"{rate:.1f}")
    bar.update(1)

    validate = done == run.total or (cfg.val.every > 0 and done % cfg.val.every == 0)
    save = done % cfg.train.checkpoint_every == 0 or done == run.total
    # A finite loss can still leave inf weights (a huge lr): never validate or save them.
    if (validate or save) and not _finite_parameters(run.model):
        raise TrainingDiverged(
            f"the weights hold NaN/inf after step {done} (lr {lr:.3g}). "
            f"{_last_good(out)} Lower train.lr."
        )
    if validate and save and done == run.total and main:
        # The trained weights are safe before the final validation runs (and may fail).
        run.checkpoint(out / "last.pt", done)
    if validate:
        began = time.perf_counter()
        run.last_val = {"step": done, **run.validator(run.model)}
        run.tick += time.perf_counter() - began  # images/s counts training time only
        if run.log is not None:  # rank 0's
            run.log.write(run.last_val)
            bins = " ".join(f"{k} {_fmt(x)}" for k, x in run.last_val["miou_bins"].items())
            edges = " ".join(
                f"{k} {_fmt(x)}" for k, x in run.last_val["boundary_miou_bins"].items()
            )
            bar.write(f"step {done}: val mIoU {_fmt(run.last_val['miou'])} (per bin: {bins}); "
                      f"mBoundaryIoU {_fmt(run.last_val['boundary_miou'])} (per bin: "
                      f"{edges})")  # fmt: skip
        miou = run.last_val["miou"]
        if miou is not None and (run.best_miou is None or miou > run.best_miou):
            run.best_miou, run.best_step = miou, done
            if main:
                run.checkpoint(out / "best.pt", done)
    if save:
        if main:
            run.checkpoint(out / "last.pt", done)
        barrier()


def _val_window(cfg: DictConfig, patch_size: int, precision: str) -> WindowConfig:
    """The validation windows, checked against the model before training starts.

    Raises:
        ValueError: naming ``val.window``/``val.stride``/``val.scale``/``val.batch_size``.
    """
    v = cfg.val
    try:
        augment = cfg.data.augment  # the normalisation the training crops get
        tta = None
        if v.tta_scales is not None:
            tta = TTAConfig(tuple(v.tta_scales), bool(v.tta_flip), v.tta_rule, v.tta_size)
        window = WindowConfig(v.window, v.stride, v.scale, v.batch_size, precision,
                              mean=tuple(augment.mean), std=tuple(augment.std),
                              tta=tta)  # fmt: skip
        window.check_patch(patch_size)
    except ValueError as exc:
        raise ValueError(
            f"bad validation windows (val.window={v.window}, val.stride={v.stride}): {exc}"
        ) from None
    return window


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def _last_good(out: Path) -> str:
    last = out / "last.pt"
    if last.is_file():
        return f"The last good checkpoint is {last}."
    return "No checkpoint was written yet."

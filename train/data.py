"""Training data: the datasets a config names, a resumable step sampler, k crops per frame,
class weights.

Reproducibility is built into the sampling rather than into RNG states: the sampler turns a
global *position* (how many frames the whole run has drawn so far) into a frame index (one
shuffled permutation per epoch, from the seed) and into a per-sample augmentation seed. So a
run resumed at step s draws exactly the frames and crops an uninterrupted run draws at step s,
whatever the number of loader workers, and the ranks of a DDP run together draw what one
process with the same global batch draws.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch.utils.data import DataLoader, Dataset, Sampler

from claravid.dsp import compute_complexities
from claravid.segmentation import ClaraVidSegmentation
from claravid.targets import UAVidSegmentation
from claravid.transforms import AugmentConfig, eval_transforms, train_transforms
from eval.bins import quantile_bins
from eval.distributed import gather_in_order, shard_indices


class EmptySplitError(ValueError):
    """A dataset split with no frame in it."""


def _augment(cfg: DictConfig) -> AugmentConfig:
    return AugmentConfig(**OmegaConf.to_container(cfg.data.augment))  # type: ignore[arg-type]


def _uavid(root: str | Path, split: str, palette: str, transforms: Any) -> UAVidSegmentation:
    kwargs: dict[str, Any] = {"root": root, "split": split, "transforms": transforms}
    # Older UAVidSegmentation versions read the uavid palette only and take no palette argument.
    if "palette" in inspect.signature(UAVidSegmentation).parameters:
        kwargs["palette"] = palette
    elif palette != "uavid":
        raise ValueError(f"UAVid labels are UAVid classes: set data.palette=uavid, not {palette}")
    return UAVidSegmentation(**kwargs)


def _claravid(cfg: DictConfig, root: str | Path, split: str, transforms: Any) -> Dataset:
    d = cfg.data
    return ClaraVidSegmentation(
        root,
        split=split,
        missions=list(d.missions) if d.missions is not None else None,
        altitude=list(d.altitude) if d.altitude is not None else None,
        direction=list(d.direction) if d.direction is not None else None,
        palette=d.palette,
        transforms=transforms,
        split_config={
            "block_size": d.split.block_size,
            "fractions": tuple(d.split.fractions),
            "seed": d.split.seed,
            "val_missions": tuple(d.split.val_missions),
            "test_missions": tuple(d.split.test_missions),
        },
        label_cache=d.label_cache,
    )


def _check_root(root: str | None, key: str) -> Path:
    if root is None or not Path(root).is_dir():
        raise FileNotFoundError(
            f"{key}={root} is not a folder: point {key} at the dataset root "
            f"(e.g. {key}=/data/claravid; `make demo` generates one at runs/demo/data)"
        )
    return Path(root)


def build_train_dataset(cfg: DictConfig) -> Dataset:
    """The training split, without transforms (`CropDataset` augments it).

    Raises:
        FileNotFoundError: ``data.root`` missing.
        EmptySplitError: the split selects no frame.
    """
    root = _check_root(cfg.data.root, "data.root")
    if cfg.data.dataset == "uavid":
        ds = _uavid(root, cfg.data.train_split, cfg.data.palette, None)
    else:
        ds = _claravid(cfg, root, cfg.data.train_split, None)
    if len(ds) == 0:
        raise EmptySplitError(
            f"the {cfg.data.train_split!r} split of {root} holds no frame with this selection "
            "(data.missions/altitude/direction/split); widen the selection or change data.split"
        )
    return ds


def build_val_dataset(cfg: DictConfig) -> Dataset:
    """The validation split with evaluation transforms (normalisation only)."""
    key = "data.val_root" if cfg.data.val_root is not None else "data.root"
    root = _check_root(cfg.data.val_root or cfg.data.root, key)
    transforms = eval_transforms(_augment(cfg))
    if cfg.data.val_dataset == "uavid":
        ds = _uavid(root, cfg.data.val_split, cfg.data.palette, transforms)
    else:
        ds = _claravid(cfg, root, cfg.data.val_split, transforms)
    if len(ds) == 0:
        raise EmptySplitError(
            f"the {cfg.data.val_split!r} split of {root} holds no frame with this selection; "
            "widen the selection or change data.split (validation needs images)"
        )
    return ds


def image_paths(dataset: Dataset) -> list[str]:
    """Each sample's RGB file, without decoding anything (for complexity)."""
    if isinstance(dataset, ClaraVidSegmentation):
        return [str(f.paths["rgb"]) for f in dataset.frames]
    return [str(p) for p in dataset.images]  # type: ignore[attr-defined]


def sample_seed(seed: int, position: int) -> int:
    """The augmentation seed of the frame drawn at global ``position`` (independent streams)."""
    return int(np.random.SeedSequence([seed, position]).generate_state(1)[0])


class StepSampler(Sampler):
    """Endless ``(frame index, augmentation seed)`` pairs for one rank, from a given step.

    Step s of the run draws the global positions ``[s·F, (s+1)·F)``, F = frames per step over
    all ranks and micro-batches; micro-batch m of rank r takes the chunk ``m·W + r`` of F/(W·A)
    consecutive positions. Position p is frame ``perm_e[p mod n]`` of epoch e = p div n (one
    permutation per epoch, seeded), so epochs roll over inside a step without a short batch.

    With ``groups`` (``data.sampler: complexity_balanced``: the frames of each delentropy bin),
    position p draws from group p mod G, as the (p div G)-th draw of that group's own epochs of
    permutations: every G consecutive draws hold one frame of each group, whatever the group
    sizes. Still a function of the position alone, so resume and DDP hold as above.

    Args:
        num_frames: frames in the training split (n).
        frames_per_step: F, over all ranks and micro-batches.
        seed: the run's seed.
        rank: this process's rank, W = world_size.
        grad_accum: A, micro-batches per optimiser step on each rank.
        start_step: first step to draw (resume).
        groups: frame indices per group to draw from in turn (None: all frames uniformly).
    """

    def __init__(
        self,
        num_frames: int,
        frames_per_step: int,
        seed: int,
        rank: int = 0,
        world_size: int = 1,
        grad_accum: int = 1,
        start_step: int = 0,
        groups: list[list[int]] | None = None,
    ) -> None:
        if groups is not None and (not groups or not all(groups)):
            raise ValueError("every sampler group needs at least one frame")
        if frames_per_step % (world_size * grad_accum):
            raise ValueError(
                f"{frames_per_step} frames per step do not split into {world_size} rank(s) × "
                f"{grad_accum} micro-batch(es)"
            )
        self.n, self.frames_per_step, self.seed = num_frames, frames_per_step, seed
        self.rank, self.world_size, self.grad_accum = rank, world_size, grad_accum
        self.micro = frames_per_step // (world_size * grad_accum)
        self.start_step = start_step
        self.groups = [np.asarray(g, dtype=np.int64) for g in groups or [range(num_frames)]]
        self._perms: dict[tuple[int, int], np.ndarray] = {}

    def frame(self, position: int) -> int:
        """The frame index drawn at a global position."""
        g = position % len(self.groups)
        group = self.groups[g]
        draw = position // len(self.groups)
        epoch = draw // len(group)
        if (g, epoch) not in self._perms:
            seed = self.seed * 1_000_003 + epoch + 7919 * g
            perm = torch.randperm(len(group), generator=torch.Generator().manual_seed(seed))
            # Keep only the current epoch of each group (the sampler runs for ever).
            self._perms = {k: v for k, v in self._perms.items() if k[0] != g}
            self._perms[g, epoch] = group[perm.numpy()]
        return int(self._perms[g, epoch][draw % len(group)])

    def positions(self, step: int) -> list[int]:
        """This rank's global positions of ``step``, micro-batch after micro-batch."""
        out = []
        for m in range(self.grad_accum):
            first = step * self.frames_per_step + (m * self.world_size + self.rank) * self.micro
            out.extend(range(first, first + self.micro))
        return out

    def __iter__(self) -> Iterator[tuple[int, int]]:
        step = self.start_step
        while True:
            for p in self.positions(step):
                yield self.frame(p), sample_seed(self.seed, p)
            step += 1


class CropDataset(Dataset):
    """k augmented crops of one decoded frame per item, each crop from its own seed.

    Decoding a full frame costs far more than cropping and augmenting it (a 4032×3024 JPEG is
    ~95 ms, a 630² crop's augmentations a few ms), so k > 1 multiplies images per decode.

    Args:
        base: a dataset of uint8 samples (no transforms).
        augment: the augmentation config (crop size, probabilities ...).
        crops_per_frame: k.
    """

    def __init__(self, base: Dataset, augment: AugmentConfig, crops_per_frame: int = 1) -> None:
        self.base = base
        self.transform = train_transforms(augment)
        self.k = crops_per_frame

    def __len__(self) -> int:
        return len(self.base)  # type: ignore[arg-type]

    def __getitem__(self, item: tuple[int, int]) -> dict[str, torch.Tensor]:
        index, seed = item
        sample = self.base[index]
        images, masks = [], []
        for j in range(self.k):
            # Seeding the pipeline per crop makes the crop a function of (position, j) alone.
            self.transform.pipeline.set_random_seed((seed + j) % 2**32)
            out = self.transform({"image": sample["image"], "mask": sample["mask"]})
            images.append(out["image"])
            masks.append(out["mask"].long())
        return {"image": torch.stack(images), "mask": torch.stack(masks)}


def collate_crops(items: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Concatenate the k crops of each frame into one batch [B·k, ...]."""
    return {key: torch.cat([it[key] for it in items]) for key in ("image", "mask")}


def check_batch(cfg: DictConfig, world_size: int) -> int:
    """Frames per optimiser step; raises unless the batch splits into ranks × micro-batches × k."""
    t, k = cfg.train, cfg.data.crops_per_frame
    per_step = world_size * t.grad_accum * k
    if t.batch_size % per_step:
        raise ValueError(
            f"train.batch_size={t.batch_size} must be a multiple of ranks ({world_size}) × "
            f"train.grad_accum ({t.grad_accum}) × data.crops_per_frame ({k}) = {per_step}"
        )
    return t.batch_size // k


def build_train_loader(
    dataset: Dataset,
    cfg: DictConfig,
    *,
    rank: int = 0,
    world_size: int = 1,
    start_step: int = 0,
    pin_memory: bool = False,
    groups: list[list[int]] | None = None,
) -> DataLoader:
    """An endless loader of micro-batches for this rank, starting at ``start_step``.

    ``groups``: frame indices per delentropy bin for ``data.sampler: complexity_balanced``.
    """
    t, k = cfg.train, cfg.data.crops_per_frame
    frames_per_step = check_batch(cfg, world_size)
    sampler = StepSampler(
        len(dataset), frames_per_step, cfg.seed, rank, world_size, t.grad_accum, start_step, groups
    )
    workers = cfg.data.num_workers
    return DataLoader(
        CropDataset(dataset, _augment(cfg), k),
        batch_size=sampler.micro,
        sampler=sampler,
        num_workers=workers,
        collate_fn=collate_crops,
        pin_memory=pin_memory,
        # No cv2.setNumThreads(1) in the workers: in a child forked after the parent used
        # OpenCV's thread pool (delentropy of the val set) it deadlocks.
        persistent_workers=workers > 0,
        prefetch_factor=4 if workers > 0 else None,
    )


def class_frequencies(dataset: Dataset, num_classes: int) -> np.ndarray:
    """Pixels per class of the training split (ClaraVid's are cached; others counted here)."""
    if isinstance(dataset, ClaraVidSegmentation):
        return dataset.class_frequencies(progress=False)
    counts = np.zeros(num_classes, dtype=np.int64)
    for i in range(len(dataset)):  # type: ignore[arg-type]
        mask = dataset[i]["mask"].numpy().ravel()
        counts += np.bincount(mask[mask < num_classes], minlength=num_classes)
    return counts


def class_weights(counts: np.ndarray, method: str) -> torch.Tensor | None:
    """Loss weights per class from pixel counts; classes absent from training get 0.

    - ``none``: no weighting (None).
    - ``inverse``: 1/frequency, scaled to mean 1 over present classes.
    - ``median_frequency``: median(frequency)/frequency (Eigen & Fergus; SegNet).
    - ``log_inverse``: 1/ln(1.02 + frequency) (ENet), in [1, ~50].
    """
    if method == "none":
        return None
    counts = np.asarray(counts, dtype=np.float64)
    present = counts > 0
    if not present.any():
        raise ValueError("the training split has no labelled pixel: cannot weight classes")
    freq = counts / counts.sum()
    w = np.zeros_like(freq)
    if method == "inverse":
        w[present] = 1.0 / freq[present]
        w[present] /= w[present].mean()
    elif method == "median_frequency":
        w[present] = np.median(freq[present]) / freq[present]
    elif method == "log_inverse":
        w[present] = 1.0 / np.log(1.02 + freq[present])
    else:
        raise ValueError(f"unknown class weighting {method!r}")
    return torch.tensor(w, dtype=torch.float32)


def sharded_delentropy(paths: list[str]) -> np.ndarray:
    """Delentropy of each image (NaN if unreadable), each rank measuring every W-th one.

    Values come from the DSP cache when the files were profiled before (``claravid-dsp``,
    ``make demo``); every rank gets all values, in order.
    """
    mine = shard_indices(len(paths))
    results, _errors = compute_complexities([paths[i] for i in mine], "delent")
    values = {r.image_path: r.complexity for r in results}
    ours = [values.get(paths[i], math.nan) for i in mine]
    return np.asarray(gather_in_order(ours, mine), dtype=np.float64)


def complexity_groups(dataset: Dataset, bins: int) -> list[list[int]]:
    """Training frames split into ``bins`` delentropy quantile bins (``eval.quantile_bins``)."""
    paths = image_paths(dataset)
    values = sharded_delentropy(paths)
    bad = [p for p, v in zip(paths, values, strict=True) if not math.isfinite(v)]
    if bad:
        raise ValueError(
            f"complexity_balanced sampling cannot read {len(bad)} image(s), e.g. {bad[0]}"
        )
    if bins > len(paths):
        raise ValueError(f"data.sampler_bins={bins} is more than the {len(paths)} training frames")
    return [list(b.indices) for b in quantile_bins(values, paths, bins)]

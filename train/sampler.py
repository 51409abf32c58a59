"""Which training frame comes when: a resumable, rank-aware step sampler.

Reproducibility is built into the sampling rather than into RNG states: the sampler turns a
global *position* (how many frames the whole run has drawn so far) into a frame index (one
shuffled permutation per epoch, from the seed) and into a per-sample augmentation seed. So a
run resumed at step s draws exactly the frames and crops an uninterrupted run draws at step s,
whatever the number of loader workers, and the ranks of a DDP run together draw what one
process with the same global batch draws. ``torch``'s ``DistributedSampler`` strides ranks
through one epoch and cannot start mid-epoch, so it can give neither.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import torch
from torch.utils.data import Sampler

from claravid.dsp import compute_complexities
from claravid.eval.analysis.bins import quantile_bins
from claravid.infra.distributed import gather_in_order, shard_indices


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
        every = [list(range(num_frames))]
        self.groups = [np.asarray(g, dtype=np.int64) for g in groups or every]
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
        out: list[int] = []
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


def complexity_groups(paths: list[str], bins: int) -> list[list[int]]:
    """Image indices of each of ``bins`` delentropy quantile bins (as
    `claravid.eval.analysis.bins.quantile_bins`)."""
    values = sharded_delentropy(paths)
    bad = [p for p, v in zip(paths, values, strict=True) if not math.isfinite(v)]
    if bad:
        raise ValueError(
            f"complexity_balanced sampling cannot read {len(bad)} image(s), e.g. {bad[0]}"
        )
    if bins > len(paths):
        raise ValueError(f"data.sampler_bins={bins} is more than the {len(paths)} training frames")
    return [list(b.indices) for b in quantile_bins(values, paths, bins)]

"""The step sampler's positions, reproducible crops, class weights."""

import itertools

import numpy as np
import pytest
import torch

from claravid.data.samples import normalise
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import AugmentConfig, train_transforms
from claravid.train.data import CropDataset, class_weights, collate_crops
from claravid.train.sampler import StepSampler


def draw(sampler, n):
    return list(itertools.islice(iter(sampler), n))


def test_every_frame_once_per_epoch_and_epochs_differ():
    s = StepSampler(num_frames=10, frames_per_step=4, seed=0)
    items = draw(s, 20)
    first, second = [i for i, _ in items[:10]], [i for i, _ in items[10:]]
    assert sorted(first) == list(range(10)) and sorted(second) == list(range(10))
    assert first != second
    seeds = [seed for _, seed in items]
    assert len(set(seeds)) == 20  # one augmentation seed per drawn position


def test_resuming_at_a_step_draws_what_the_run_would_have_drawn():
    full = draw(StepSampler(7, 4, seed=5), 40)
    assert draw(StepSampler(7, 4, seed=5, start_step=3), 28) == full[12:]
    assert draw(StepSampler(7, 4, seed=6), 40) != full


def test_ranks_and_micro_batches_partition_the_global_batch():
    one = draw(StepSampler(9, 8, seed=1, grad_accum=2), 16)  # 2 steps, micro-batches of 4
    r0 = draw(StepSampler(9, 8, seed=1, rank=0, world_size=2), 8)
    r1 = draw(StepSampler(9, 8, seed=1, rank=1, world_size=2), 8)
    # Step s: rank r holds what micro-batch r of the single process holds.
    assert r0[:4] == one[:4] and r1[:4] == one[4:8]
    assert r0[4:] == one[8:12] and r1[4:] == one[12:]
    with pytest.raises(ValueError, match="do not split"):
        StepSampler(9, 6, seed=1, world_size=4)


def test_crops_are_a_function_of_the_seed(claravid_root):
    base = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    crops = CropDataset(base, AugmentConfig(crop_height=28, crop_width=28), crops_per_frame=3)
    a, b, c = crops[(2, 11)], crops[(2, 11)], crops[(2, 12)]
    assert a["image"].shape == (3, 3, 28, 28) and a["mask"].shape == (3, 28, 28)
    assert torch.equal(a["image"], b["image"]) and torch.equal(a["mask"], b["mask"])
    assert not torch.equal(a["image"], c["image"])
    assert not torch.equal(a["image"][0], a["image"][1])  # k crops differ from each other
    batch = collate_crops([a, c])
    assert batch["image"].shape == (6, 3, 28, 28) and batch["mask"].shape == (6, 28, 28)
    # uint8 until the device: a quarter of float32's bytes through the workers' shared memory
    assert batch["image"].dtype == torch.uint8 and batch["mask"].dtype == torch.uint8


def test_crops_normalised_on_the_device_are_the_normalising_pipeline_s(claravid_root):
    """Leaving the normalisation to the device changes neither the random stream nor, beyond
    float rounding, the values: the same seed through the pipeline that normalises gives them."""
    augment = AugmentConfig(
        crop_height=28, crop_width=28, mean=(0.2, 0.4, 0.6), std=(0.5, 0.25, 0.2)
    )
    base = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    crop = CropDataset(base, augment)[(1, 77)]
    reference = train_transforms(augment, normalize=True)  # ends with albumentations' Normalize
    reference.pipeline.set_random_seed(77)
    expected = reference(base[1])
    got = normalise(crop["image"], augment.mean, augment.std)[0]
    torch.testing.assert_close(got, expected["image"], rtol=0, atol=1e-6)
    torch.testing.assert_close(crop["mask"][0], expected["mask"].to(torch.uint8), rtol=0, atol=0)


def test_normalise_by_hand():
    image = torch.tensor([0, 51, 255], dtype=torch.uint8).view(1, 3, 1, 1).expand(2, 3, 1, 2)
    out = normalise(image, mean=(0.0, 0.1, 0.5), std=(1.0, 0.5, 0.25))
    # channel 0: 0/255 = 0; channel 1: (0.2 - 0.1) / 0.5 = 0.2; channel 2: (1 - 0.5) / 0.25 = 2
    expected = torch.tensor([0.0, 0.2, 2.0]).view(1, 3, 1, 1).expand(2, 3, 1, 2)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-6)
    # A float image within the normalised range ([-0.25, 0.25] for mean 0.5, std 2) is normalised
    # already; tests/claravid/data/test_samples.py pins the refusal of the others.
    already = torch.rand(3, 4, 4) / 2 - 0.25
    assert normalise(already, (0.5,) * 3, (2.0,) * 3) is already


def test_class_weights_by_hand():
    counts = np.array([700, 200, 100, 0])
    assert class_weights(counts, "none") is None
    inv = 1 / np.array([0.7, 0.2, 0.1])
    np.testing.assert_allclose(
        class_weights(counts, "inverse"), [*(inv / inv.mean()), 0], rtol=1e-6
    )
    np.testing.assert_allclose(
        class_weights(counts, "median_frequency"), [0.2 / 0.7, 1.0, 2.0, 0], rtol=1e-6
    )
    np.testing.assert_allclose(
        class_weights(counts, "log_inverse"),
        [1 / np.log(1.72), 1 / np.log(1.22), 1 / np.log(1.12), 0],
        rtol=1e-6,
    )
    with pytest.raises(ValueError, match="no labelled pixel"):
        class_weights(np.zeros(3), "inverse")


def test_complexity_balanced_draws_each_bin_in_turn():
    groups = [[0, 1, 2, 3, 4, 5], [6, 7], [8]]  # bins of unequal size
    s = StepSampler(9, 6, seed=2, groups=groups)
    frames = [i for i, _ in draw(s, 60)]
    for start in range(0, 60, 3):  # every 3 consecutive draws: one frame of each bin
        assert [f in g for f, g in zip(frames[start : start + 3], groups, strict=True)] == [
            True
        ] * 3
    assert sorted(frames[0:18:3]) == [0, 1, 2, 3, 4, 5]  # each bin cycles through its epochs
    assert frames.count(8) == 20 and frames.count(6) == 10
    # Resumable and shardable as the uniform sampler: a function of the position only.
    resumed = StepSampler(9, 6, seed=2, groups=groups, start_step=4)
    assert draw(resumed, 36) == draw(StepSampler(9, 6, seed=2, groups=groups), 60)[24:]
    r1 = draw(StepSampler(9, 6, seed=2, rank=1, world_size=2, groups=groups), 6)
    full = draw(StepSampler(9, 6, seed=2, groups=groups), 12)
    assert r1 == full[3:6] + full[9:12]
    with pytest.raises(ValueError, match="at least one frame"):
        StepSampler(9, 6, seed=2, groups=[[0], []])


def test_uavid_class_frequencies_count_the_label_files(uavid_root):
    from claravid.data.palettes import load_palette
    from claravid.data.targets import UAVidSegmentation
    from claravid.train.data import class_frequencies

    ds = UAVidSegmentation(uavid_root, split="train", palette="uavid")
    counts = class_frequencies(ds, 8)
    # The fixture's labels: 3 frames of 48×64 in blocks of random UAVid ids, re-drawn here.
    rng = np.random.default_rng(0)
    expected = np.zeros(8, dtype=np.int64)
    for _ in range(3):
        ids = np.repeat(np.repeat(rng.integers(0, 8, (6, 8)), 8, 0), 8, 1)
        rng.integers(0, 50, (48, 64, 3))  # the image noise the fixture draws next
        expected += np.bincount(ids.ravel(), minlength=8)
    np.testing.assert_array_equal(counts, expected)
    assert counts.sum() == 3 * 48 * 64 and len(load_palette("uavid").names) == 8

"""Label budgets (data.budget): whole sequences or blocks, deterministic, nested, recorded."""

import hashlib
import itertools
import json
import math
from collections import defaultdict

import numpy as np
import pytest

from claravid.data.palettes import load_palette
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.targets import UAVidSegmentation
from claravid.io import modalities
from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config
from claravid.train.budget import BudgetError, apply_budget, draw_budget, draw_units
from claravid.train.cli import main
from claravid.train.config import ConfigError
from tests.tiny import tiny

CURVE = (0.01, 0.05, 0.1, 0.25, 1.0)
#: Frames per UAVid training sequence of the tree below: 11 frames, sequences of unequal size.
SEQUENCES = {"seq1": 1, "seq2": 2, "seq3": 3, "seq4": 2, "seq5": 3}


@pytest.fixture(scope="module")
def uavid_sequences(tmp_path_factory):
    """uavid_train with the sequences of `SEQUENCES` and uavid_val/seq9 with 3 frames, 64×48."""
    root = tmp_path_factory.mktemp("uavid_seqs")
    colors = load_palette("uavid").colors
    rng = np.random.default_rng(3)
    for split, sequences in (("train", SEQUENCES), ("val", {"seq9": 3})):
        for seq, frames in sequences.items():
            for frame in range(frames):
                ids = np.repeat(np.repeat(rng.integers(0, 8, (6, 8)), 8, 0), 8, 1)
                image = (colors[ids] * 0.8 + rng.integers(0, 50, (48, 64, 3))).astype(np.uint8)
                base = root / f"uavid_{split}" / seq
                modalities._write_image(base / "Images" / f"{frame:06d}.png", image)
                modalities.write_seg_color(base / "Labels" / f"{frame:06d}.png", colors[ids])
    return root


def _whole_units(labels, kept):
    """Every unit is kept whole or not at all."""
    members = defaultdict(set)
    for i, label in enumerate(labels):
        members[label].add(i)
    kept = set(kept)
    return all(m <= kept or not (m & kept) for m in members.values())


@pytest.mark.parametrize("seed", [0, 1, 7])
def test_draw_keeps_whole_units_nested_and_the_closest_prefix(seed):
    # 10 units of 1..10 items (55 items), shuffled so that item order says nothing of the unit.
    labels = [f"u{n:02d}" for n in range(1, 11) for _ in range(n)]
    labels = [labels[i] for i in np.random.default_rng(99).permutation(len(labels))]
    full_order, everything = draw_units(labels, 1.0, seed)
    assert everything == list(range(55)) and sorted(full_order) == sorted(set(labels))
    size = {u: labels.count(u) for u in full_order}
    previous: set[int] = set()
    for fraction in (0.01, 0.05, 0.1, 0.25, 0.5, 0.9, 1.0):
        units, kept = draw_units(labels, fraction, seed)
        assert (units, kept) == draw_units(labels, fraction, seed)  # deterministic
        assert _whole_units(labels, kept)
        assert units == full_order[: len(units)]  # a prefix of the seed's one order
        assert set(kept) >= previous  # nested
        previous = set(kept)
        # The rule, stated by brute force: the prefix (k >= 1) whose items come closest to
        # fraction x 55, the larger on a tie.
        counts = [sum(size[u] for u in full_order[:k]) for k in range(1, 11)]
        target = fraction * 55
        best = min(range(10), key=lambda k: (abs(counts[k] - target), -k))
        assert len(units) == best + 1, (fraction, counts, units)
        assert len(kept) == counts[best]


def test_draw_seeds_differ_and_one_unit_is_the_least():
    labels = [f"u{n}" for n in range(20) for _ in range(3)]
    orders = {tuple(draw_units(labels, 1.0, seed)[0]) for seed in range(5)}
    assert len(orders) == 5
    units, kept = draw_units(labels, 0.001, 0)  # target 0.06 items: still one whole unit
    assert len(units) == 1 and len(kept) == 3


@pytest.mark.parametrize("fraction", [0.0, -0.1, 1.5, math.nan])
def test_draw_refuses_a_fraction_outside_0_1(fraction):
    with pytest.raises(BudgetError, match=r"data\.budget"):
        draw_units(["a", "b"], fraction, 0)


def test_uavid_budget_takes_whole_sequences_and_records_them(uavid_sequences):
    budgets = {}
    for fraction in CURVE:
        ds = UAVidSegmentation(uavid_sequences, split="train")
        budget = draw_budget(ds, fraction, "auto", seed=4)
        assert budget.unit == "sequence" and budget.num_images == 11
        apply_budget(ds, budget)
        sequences = {p.parent.parent.name for p in ds.images}
        if fraction < 1:
            assert budget.num_units == 5 and sequences == set(budget.units)
        else:  # 1.0 draws nothing: every image
            assert budget.units is None and sequences == set(SEQUENCES)
        assert len(ds) == sum(SEQUENCES[s] for s in sequences)  # whole sequences only
        keys = sorted(p.relative_to(uavid_sequences).with_suffix("").as_posix() for p in ds.images)
        assert list(budget.keys) == keys
        expected = hashlib.sha256("".join(k + "\n" for k in keys).encode()).hexdigest()
        assert budget.digest == expected
        assert budget.record()["kept_images"] == len(keys) and "keys" not in budget.record()
        budgets[fraction] = set(keys)
    assert budgets[1.0] == {
        f"uavid_train/{s}/Images/{f:06d}" for s, n in SEQUENCES.items() for f in range(n)
    }
    for small, large in itertools.pairwise(CURVE):
        assert budgets[small] <= budgets[large]
    # 1 % of 11 images is 0.11: one sequence, never none.
    assert len(draw_budget(UAVidSegmentation(uavid_sequences), 0.01, seed=4).units) == 1


def test_claravid_budget_takes_whole_blocks_or_passes(claravid_root):
    for unit in ("block", "pass"):
        ds = ClaraVidSegmentation(claravid_root, split="train", palette="uavid")
        labels = ds.block_ids() if unit == "block" else [f.key.rsplit("/", 1)[0] for f in ds.frames]
        budget = draw_budget(ds, 0.25, unit, seed=0)
        assert budget.unit == unit and 0 < len(budget.keys) < len(ds)
        assert _whole_units(labels, budget.indices)
        assert {labels[i] for i in budget.indices} == set(budget.units)
    for fraction in (0.5, 1.0):  # checked also where nothing is drawn
        with pytest.raises(BudgetError, match=r"data\.budget_by: 'sequence'"):
            draw_budget(ClaraVidSegmentation(claravid_root, split="train"), fraction, "sequence")


@pytest.mark.parametrize("bad", ["data.budget=0", "data.budget=1.01", "data.budget=-1",
                                 "data.budget_by=image"])  # fmt: skip
def test_config_refuses_a_bad_budget_in_one_line(bad, claravid_root, tmp_path, capsys):
    args = tiny(claravid_root, tmp_path / "run", bad)
    with pytest.raises(ConfigError, match=bad.split("=")[0]):
        load_config("demo", args)
    assert main(["--config", "demo", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and bad.split("=")[0] in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_a_unit_the_dataset_lacks_stops_the_run_in_one_line(claravid_root, tmp_path, capsys):
    args = tiny(claravid_root, tmp_path / "run", "data.budget=0.5", "data.budget_by=sequence")
    assert main(["--config", "demo", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "data.budget_by: 'sequence'" in err
    assert "block, pass, mission, folder" in err and not (tmp_path / "run").exists()


def test_a_budgeted_uavid_run_records_its_images(uavid_sequences, tmp_path, capsys):
    out = tmp_path / "run"
    args = tiny(uavid_sequences, out, "data.dataset=uavid", "data.val_dataset=uavid",
                "data.val_split=val", "data.budget=0.25", "data.budget_seed=4",
                "train.steps=1", "val.every=0")  # fmt: skip
    assert main(["--config", "demo", *args]) == 0
    said = capsys.readouterr().out
    expected = draw_budget(UAVidSegmentation(uavid_sequences), 0.25, seed=4)
    assert "data.budget=0.25 by sequence (seed 4)" in said and expected.digest[:12] in said
    assert "best.pt, budget.json" in said  # the last lines name it among the results
    ckpt = read_checkpoint(out / "last.pt")
    assert ckpt["budget"] == expected.record()
    assert ckpt["classes"] == list(load_palette("uavid").names) and ckpt["init"] is None
    written = json.loads((out / "budget.json").read_text())
    assert written["keys"] == list(expected.keys) and written["digest"] == expected.digest


def test_a_run_of_every_image_records_them_and_writes_no_budget_file(uavid_sequences, tmp_path):
    out = tmp_path / "run"
    args = tiny(uavid_sequences, out, "data.dataset=uavid", "data.val_dataset=uavid",
                "data.val_split=val", "train.steps=1", "val.every=0")  # fmt: skip
    assert main(["--config", "demo", *args]) == 0
    record = read_checkpoint(out / "last.pt")["budget"]
    assert record["fraction"] == 1.0 and record["kept_images"] == record["num_images"] == 11
    assert record["units"] is None and not (out / "budget.json").exists()


class _Layout:
    """A real dataset of another layout as the readers list one: ``root``, ``dataset``, and
    ``images`` with their ``masks`` beside (paths only: the draw reads no pixel)."""

    def __init__(self, root, dataset, stems, folder="JPEGImages"):
        self.root, self.dataset = root, dataset
        self.images = [root / folder / f"{s}.jpg" for s in stems]
        self.masks = [root / "SegmentationClass" / f"{s}.png" for s in stems]


def test_aeroscapes_sequences_are_drawn_whole_with_their_masks(tmp_path):
    # 4 sequences of 1, 2, 3 and 4 frames, named as AeroScapes names them (SSSSSS_FFF).
    stems = [f"{seq:06d}_{f:03d}" for seq in range(1, 5) for f in range(1, seq + 1)]
    ds = _Layout(tmp_path, "aeroscapes", stems)
    budget = draw_budget(ds, 0.3, seed=2)
    assert budget.unit == "sequence" and budget.num_units == 4
    apply_budget(ds, budget)
    kept = {p.stem.split("_")[0] for p in ds.images}
    assert kept == set(budget.units) and len(ds.images) == sum(int(s) for s in kept)
    assert [m.stem for m in ds.masks] == [p.stem for p in ds.images]  # masks kept beside


def test_a_flat_folder_has_no_share_below_1_and_says_so(tmp_path):
    flat = _Layout(tmp_path, "udd6", [f"DJI_{i:04d}" for i in range(6)], folder="train/src")
    with pytest.raises(BudgetError, match=r"all in one folder \(train/src\).*data\.budget=1\.0"):
        draw_budget(flat, 0.5)
    with pytest.raises(BudgetError, match=r"data\.budget_by: 'sequence'.*drawn by folder"):
        draw_budget(flat, 0.5, "sequence")
    every = draw_budget(flat, 1.0)  # every image: nothing to draw, nothing refused
    assert every.unit == "folder" and len(every.keys) == 6

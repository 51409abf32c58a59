"""Training's label-cache preparation: what it cannot do is said before the first step, in one
line, with advice that applies to ``claravid-train``; and what its loader workers get pickles,
for workers started by spawn."""

import pytest
import torch
from torch.utils.data import DataLoader

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import AugmentConfig
from claravid.train import load_config
from claravid.train.cli import main
from claravid.train.data import CropDataset, build_train_dataset, collate_crops
from tests.tiny import tiny


def _error_lines(capsys):
    # The tiny tree's split is off its targets: that warning is not the error under test.
    lines = capsys.readouterr().err.strip().splitlines()
    return [line for line in lines if "warning: " not in line]


@pytest.mark.parametrize("workers", [0, 1])
def test_a_truncated_panoptic_png_stops_training_before_the_first_step(
    writable_root, tmp_path, capsys, workers
):
    out = tmp_path / "run"
    args = tiny(writable_root, out, "train.steps=2", "val.every=0", f"data.num_workers={workers}")
    pan = build_train_dataset(load_config("demo", args)).frames[2].paths["pan_seg"]
    pan.write_bytes(pan.read_bytes()[: pan.stat().st_size // 2])
    assert main(["--config", "demo", *args]) == 2
    err = _error_lines(capsys)
    assert len(err) == 1, err
    assert err[0].startswith("claravid-train: error: ") and str(pan) in err[0]
    assert "1 frame" in err[0] and "claravid-cache" in err[0]
    assert not (out / "last.pt").exists() and not (out / "best.pt").exists()


def test_a_cache_folder_that_cannot_be_written_advises_what_training_has(
    claravid_root, tmp_path, capsys, monkeypatch
):
    blocker = tmp_path / "a file"
    blocker.write_text("")
    monkeypatch.setenv("CLARAVID_CACHE", str(blocker / "cache"))
    out = tmp_path / "run"
    assert main(["--config", "demo", *tiny(claravid_root, out, "train.steps=1")]) == 2
    (err,) = _error_lines(capsys)
    assert str(blocker / "cache" / "label_codes") in err
    assert "CLARAVID_CACHE=" in err and "data.label_cache=false" in err
    assert "--output" not in err  # claravid-train's -o is its run folder, not the cache
    assert not (out / "last.pt").exists()


def test_training_crops_from_spawned_loader_workers(claravid_root, tmp_path):
    """What training hands its DataLoader workers (``CropDataset`` over a dataset whose cache
    exists and that has read through it), to a worker started by spawn (the default on macOS,
    Windows, and Linux from Python 3.14): the same crops as in this process. At the loader, not
    a whole run: a spawned worker's start alone costs seconds here, a run ~10 s more."""
    ds = ClaraVidSegmentation(claravid_root, split="train", palette="uavid", label_cache=tmp_path,
                              mask_dtype=torch.uint8)  # fmt: skip
    assert ds.prepare_label_cache().built == len(ds)
    crops = CropDataset(ds, AugmentConfig(crop_height=28, crop_width=42), 2, by_window=True)
    items = [(3, 11), (0, 5)]
    expected = collate_crops([crops[item] for item in items])
    loader = DataLoader(crops, batch_size=2, sampler=items, num_workers=1,
                        collate_fn=collate_crops, multiprocessing_context="spawn")  # fmt: skip
    (batch,) = list(loader)
    assert batch["image"].shape == (4, 3, 28, 42) and batch["mask"].dtype == torch.uint8
    assert torch.equal(batch["image"], expected["image"])
    assert torch.equal(batch["mask"], expected["mask"])

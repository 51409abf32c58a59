"""Evaluation tests run on the tiny generated ClaraVid tree of the data tests, with tiny models."""

import pytest
import torch

from claravid import models

TINY = {
    "backbone_kwargs": {"embed_dim": 32, "depth": 4, "num_heads": 2},
    "layers": [0, 1, 2, 3],
    "features": 8,
    "out_channels": [8, 8, 8, 8],
}
# Width x height: the 48 (high) × 64 (wide) fixture frames take 4 overlapping 42×56 windows.
WINDOW = "56x42"


def tiny_model(num_classes: int = 8, seed: int = 0) -> models.Segmenter:
    torch.manual_seed(seed)
    return models.build_model("dinov2_vits14", num_classes, **TINY).eval()


@pytest.fixture(scope="session")
def model_files(claravid_root, tmp_path_factory):
    """A training-style checkpoint (config names the data and the uavid palette), a plain one
    (no config) and the dynamic-size ONNX export of the same model."""
    folder = tmp_path_factory.mktemp("models")
    model = tiny_model()
    config = {
        "data": {"root": str(claravid_root), "palette": "uavid", "split": {"seed": 0}},
        "val": {"window": 28, "scale": 1.0, "batch_size": 8},
        "other": [1, 2],
    }
    files = {
        "checkpoint": models.save_checkpoint(model, folder / "best.pt", config=config, epoch=1),
        "plain": models.save_checkpoint(model, folder / "plain.pt"),
        "onnx": folder / "model.onnx",
    }
    models.export_onnx(
        model, files["onnx"], models.ExportSettings(height=28, width=28, dynamic=True)
    )
    return files


def write_noisy_predictions(ds, folder, share: float, seed: int, num_classes: int = 8) -> None:
    """Label maps of ``ds`` (uavid ids) with a ``share`` of pixels wrong, seeded, under
    ``folder/<frame key>.png``, without ``predictions.json`` (another program's maps)."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    for i, frame in enumerate(ds.frames):
        truth = ds.read_mask(i)
        valid = np.where(truth == 255, 0, truth).astype(np.uint8)
        wrong = rng.random(valid.shape) < share
        pred = np.where(wrong, (valid + 1) % num_classes, valid).astype(np.uint8)
        (folder / frame.key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(folder / f"{frame.key}.png"), pred)


@pytest.fixture(scope="session")
def label_map_reports(claravid_root, tmp_path_factory):
    """Reports of label maps over all 36 frames of the tiny tree (uavid palette, 100 block
    resamples): ``a`` (10 % of pixels wrong), ``a_again`` (the same label maps copied to another
    folder and evaluated again: another run that agrees with ``a`` everywhere), ``b`` (20 %
    wrong); with the folders of their label maps under ``pred_<name>``."""
    import shutil

    from claravid.data.segmentation import ClaraVidSegmentation
    from claravid.eval.cli import main

    tmp = tmp_path_factory.mktemp("label_map_reports")
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    write_noisy_predictions(ds, tmp / "pred_a", 0.1, 0)
    shutil.copytree(tmp / "pred_a", tmp / "pred_a_again")
    write_noisy_predictions(ds, tmp / "pred_b", 0.2, 0)
    common = ["--data", str(claravid_root), "--split", "all", "--palette", "uavid",
              "--no-progress", "--bootstrap", "100"]  # fmt: skip
    for name in ("a", "a_again", "b"):
        assert (
            main(["--predictions", str(tmp / f"pred_{name}"), *common, "-o", str(tmp / name)]) == 0
        )
    return {"tmp": tmp, "common": common, "root": claravid_root, "ds": ds}


@pytest.fixture
def saved_figures(monkeypatch):
    """The matplotlib figures the code under test saves, by the name of the file each ends up
    in (``miou_per_bin.png``): a spy on ``Figure.savefig``, which still saves every figure, so a
    test reads what a plot shows (bar heights, image arrays) instead of only that a PNG exists."""
    from pathlib import Path

    from matplotlib.figure import Figure

    figures = {}
    save = Figure.savefig

    def spy(self, fname, *args, **kwargs):
        name = Path(fname).name
        if name.startswith("."):  # atomic_save writes ".<stem>.<random><suffix>", then renames
            stem, _, suffix = name[1:].rsplit(".", 2)
            name = f"{stem}.{suffix}"
        figures[name] = self
        return save(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", spy)
    return figures

"""Evaluation tests run on the tiny generated ClaraVid tree of the data tests, with tiny models."""

import pytest

from tests.helpers.files import write_noisy_predictions


@pytest.fixture(scope="session")
def label_map_reports(claravid_root, tmp_path_factory):
    """Reports of label maps over all 36 frames of the tiny tree (uavid palette, 100 block
    resamples): ``a`` (10 % of pixels wrong), ``a_again`` (the same label maps copied to another
    folder and evaluated again: another run that agrees with ``a`` everywhere), ``b`` (20 %
    wrong); with the folders of their label maps under ``pred_<name>``."""
    import shutil

    from claravid.data.segmentation import ClaraVidSegmentation
    from claravid.eval.cli.evaluate import main

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

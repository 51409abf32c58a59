"""`make demo` prints the split-balance warning once: in training, not again in the evaluation
of the checkpoint on the split settings it recorded."""

import pytest

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.splits import SplitBalanceWarning
from claravid.eval.cli.evaluate import main

OFF_TARGET = "points off the target"


# pyproject.toml ignores the tiny tree's 150 m warning: here what the command prints is the point.
@pytest.mark.filterwarnings("always::claravid.data.splits.SplitBalanceWarning")
def test_the_checkpoints_own_split_does_not_warn_again(
    claravid_root, model_files, tmp_path, capsys
):
    with pytest.warns(SplitBalanceWarning):  # what training printed for these settings
        ClaraVidSegmentation(claravid_root, split="val", split_config={"seed": 0})
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--no-progress", "--bootstrap", "0"]
    assert main([*argv, "--output", str(tmp_path / "a")]) == 0
    assert OFF_TARGET not in capsys.readouterr().err
    # The same data named on the command line (another spelling of the root) is the same split.
    again = [*argv, "--data", str(claravid_root / ".." / claravid_root.name), "--split", "val"]
    assert main([*again, "--output", str(tmp_path / "b")]) == 0
    assert OFF_TARGET not in capsys.readouterr().err
    # A selection named on the command line is another split (here the same missions, named):
    # its balance is news.
    named = ",".join(
        sorted({f.mission for f in ClaraVidSegmentation(claravid_root, split="all").frames})
    )
    assert main([*argv, "--missions", named, "--output", str(tmp_path / "c")]) == 0
    assert OFF_TARGET in capsys.readouterr().err

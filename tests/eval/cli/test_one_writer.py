"""An evaluation holds its output folder: a second one writing the same folder at the same time
is refused in one line and the first one's results stay (before, both exited 0 and the second
silently replaced the first); ``compare`` needs two reports."""

import json

import pytest

import claravid.eval as ev
from claravid.eval.cli.evaluate import main as eval_main
from claravid.infra.cli import UsageError
from claravid.infra.files import output_lock


def test_a_second_evaluation_of_one_output_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "report"
    out.mkdir()
    (out / "report.json").write_text(json.dumps({"first": True}))
    argv = ["--predictions", str(tmp_path / "preds"), "--data", str(tmp_path / "data"),
            "--palette", "uavid", "--output", str(out), "--no-progress"]  # fmt: skip
    with output_lock(out):  # the first evaluation, still writing
        assert eval_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert f"--output {out} is being written by another run (process " in err
        assert "wait for it to finish, or choose another --output" in err
        with pytest.raises(UsageError, match="is being written by another run"):
            ev.evaluate(out, predictions=tmp_path / "preds")
    assert json.loads((out / "report.json").read_text()) == {"first": True}
    assert not (tmp_path / ".report.lock").exists()  # released and removed
    assert eval_main(argv) == 2  # free again: now refused for its own reasons (no data)
    assert "being written" not in capsys.readouterr().err


def test_compare_of_one_report_is_refused(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    assert eval_main(["compare", str(tmp_path / "a"), "--output", str(tmp_path / "cmp")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(
        f"compare needs two or more reports, the first the baseline; got only {tmp_path / 'a'}: "
        "add the report(s) to set beside it"
    )
    assert not (tmp_path / "cmp").exists()


def test_a_missing_split_file_the_user_typed_is_named_as_theirs(model_files, tmp_path, capsys):
    # Before: "... (that path comes from the checkpoint ...; pass --data ...)".
    split = tmp_path / "my_split.txt"
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--split", str(split),
            "--output", str(tmp_path / "rep"), "--no-progress"]  # fmt: skip
    assert eval_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"claravid-eval: error: --split {split}: no such split file; pass train, val, test, all "
        "or the path of an existing split file"
    )
    assert not (tmp_path / "rep").exists()

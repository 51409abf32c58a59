"""Bad inputs a hostile new user found (issue 12 §6): one line each, before work is lost."""

import re
import shlex
import shutil

import pytest
import torch

from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config
from claravid.train.cli import main
from claravid.train.config import ConfigError
from claravid.train.validate import Validator
from tests.tiny import tiny


def _one_line(capsys, *words):
    # The tiny tree's split is off its targets: that warning is not the error under test.
    lines = capsys.readouterr().err.strip().splitlines()
    err = "\n".join(line for line in lines if "warning: " not in line)
    assert len(err.splitlines()) == 1, lines
    assert "Traceback" not in err
    for word in words:
        assert word in err, err
    return err


def test_bad_val_window_fails_before_the_first_step_and_binds_nothing(
    claravid_root, tmp_path, capsys
):
    out = tmp_path / "run"
    args = ["--config", "demo", *tiny(claravid_root, out, "train.steps=2", "val.every=0")]
    # 30 is no multiple of the tiny model's patch size 14: refused before any step, with the
    # two nearest multiples (2 and 3 patches).
    assert main([*args, "val.window=30"]) == 2
    _one_line(capsys, "val.window=30", "use 28 or 42")
    assert not (out / "last.pt").exists()
    for bad in ("val.stride=0", "train.device=tpu", "train.device=cuda:99"):
        assert main([*args, bad]) == 2, bad
        _one_line(capsys, bad.split("=")[0])
    # The corrected run takes the folder: the failed ones left no step behind.
    assert main(args) == 0
    assert read_checkpoint(out / "last.pt")["step"] == 2


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a PyTorch without a GPU")
def test_cuda_on_a_cpu_only_machine_is_one_line(claravid_root, tmp_path, capsys):
    args = tiny(claravid_root, tmp_path / "run", "train.steps=1", "train.device=cuda")
    assert main(["--config", "demo", *args]) == 2
    _one_line(capsys, "train.device 'cuda'", "use cpu")


def test_the_final_checkpoint_is_written_before_the_final_validation(
    claravid_root, tmp_path, monkeypatch
):
    out = tmp_path / "run"
    cfg = load_config("demo", tiny(claravid_root, out, "train.steps=2", "val.every=0"))

    def fail(self, model, progress=False):  # injected fault: the validation runs out of memory
        raise MemoryError("validation failed")

    monkeypatch.setattr(Validator, "__call__", fail)
    from claravid.train import train

    with pytest.raises(MemoryError):
        train(cfg)
    assert read_checkpoint(out / "last.pt")["step"] == 2  # the trained weights are kept


def test_a_copied_run_folder_resumes_and_commands_are_shell_quoted(claravid_root, tmp_path, capsys):
    first = tmp_path / "a run"  # a space: the printed commands must quote it
    args = tiny(claravid_root, first, "train.steps=2", "val.every=0")
    assert main(["--config", "demo", *args]) == 0
    text = capsys.readouterr().out
    best = first / "best.pt"
    assert f"claravid-eval --checkpoint {shlex.quote(str(best))} --output " in text
    assert f"claravid-export --checkpoint {shlex.quote(str(best))} --output " in text
    assert shlex.split(text.split("export:")[1].splitlines()[0])[2] == str(best)
    copy = tmp_path / "elsewhere"
    shutil.copytree(first, copy)
    moved = tiny(claravid_root, copy, "train.steps=2", "val.every=0")
    assert main(["--config", "demo", *moved, "--resume"]) == 0  # out_dir is no config change
    assert "already finished" in capsys.readouterr().out


def test_foreign_out_dir_does_not_advise_a_flag_train_lacks(claravid_root, tmp_path, capsys):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main(["--config", "demo", *tiny(claravid_root, foreign)]) == 2
    err = _one_line(capsys, "not written by this tool")
    assert "--overwrite" not in err


CONFIGS = {
    "list.yaml": (b"- a\n- b\n", "holds a list"),
    "scalar.yaml": (b"5\n", "holds a single value"),
    "section.yaml": (b"train: 5\n", "section train must be a mapping"),
    "binary.yaml": (bytes(range(256)), "not a YAML text file"),
}


@pytest.mark.parametrize("name", CONFIGS)
def test_a_config_file_that_is_no_mapping_of_sections(name, tmp_path, capsys):
    content, message = CONFIGS[name]
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message):
        load_config(path, ["out_dir=x", "data.root=y"])
    assert main(["--config", str(path), "out_dir=x", "data.root=y"]) == 2
    _one_line(capsys, str(path), message)


def test_overrides_as_one_string():
    cfg = load_config("demo", "train.steps=5 out_dir=x data.root=y")
    assert (cfg.train.steps, cfg.out_dir, cfg.data.root) == (5, "x", "y")


def test_uavid_labels_with_the_claravid_palette_stop_before_training(uavid_root, tmp_path, capsys):
    args = tiny(uavid_root, tmp_path / "run", "data.dataset=uavid", "data.val_dataset=uavid",
                "data.val_split=val", "data.palette=claravid", "train.steps=1")  # fmt: skip
    assert main(["--config", "demo", *args]) == 2
    _one_line(capsys, "outside palette claravid", "data.palette uavid")
    assert not (tmp_path / "run" / "last.pt").exists()


@pytest.mark.parametrize("workers", ["0", "1"])
def test_a_truncated_jpeg_is_one_line_exit_2_with_and_without_workers(
    writable_root, tmp_path, capsys, workers
):
    # With DataLoader workers torch rebuilds the worker's CorruptFileError from its text alone:
    # it must come back as that error (exit 2, the original message), not a RuntimeError
    # (a traceback, exit 1).
    for path in writable_root.rglob("left_rgb/*/*.jpg"):
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    argv = [
        a for a in tiny(writable_root, tmp_path / "run", "train.steps=2") if "num_workers" not in a
    ]
    assert main(["--config", "demo", *argv, "--workers", workers]) == 2
    err = _one_line(capsys)
    assert re.fullmatch(
        r"claravid-train: error: cannot read \S+/left_rgb/\w+/\d+\.jpg: truncated JPEG \(no "
        r"end-of-image marker\); re-copy or re-extract the file",
        err,
    ), err


@pytest.mark.parametrize("value", ["0", "1000000"])
def test_an_unusable_crop_size_is_one_line_before_training(claravid_root, tmp_path, capsys, value):
    # 10**6 failed deep inside OpenCV at the first crop (0 the config's own check refuses).
    argv = tiny(claravid_root, tmp_path / "run", f"data.augment.crop_height={value}")
    assert main(["--config", "demo", *argv]) == 2
    err = _one_line(capsys, "crop_height", value)
    assert err.startswith("claravid-train: error: ")
    assert not (tmp_path / "run" / "last.pt").exists()

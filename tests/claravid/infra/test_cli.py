"""The command-line conventions every console script shares (claravid.infra.cli)."""

import argparse
import os
import re
import stat
import subprocess
import sys
import warnings

import pytest

from claravid.infra.cli import (
    UsageError,
    add_debug_flag,
    add_progress_flag,
    add_workers_flag,
    atomic_save,
    atomic_write_text,
    check_output_dir,
    check_output_file,
    given_once,
    parse_size,
    positive_float,
    positive_int,
    run_cli,
    window_size,
)


def _parser():
    parser = argparse.ArgumentParser(prog="tool")
    parser.add_argument("--fail", choices=["usage", "value", "missing", "bug"])
    add_debug_flag(parser)
    return parser


def _run(args):
    warnings.warn("something odd", UserWarning, stacklevel=1)
    if args.fail == "usage":
        raise UsageError("bad thing; do this instead")
    if args.fail == "value":
        raise ValueError("a value is wrong")
    if args.fail == "missing":
        open("/nonexistent/file/x")  # noqa: SIM115
    if args.fail == "bug":
        raise KeyError("internal")
    return 0


@pytest.mark.parametrize("kind", ["usage", "value", "missing"])
def test_user_mistakes_exit_2_with_one_line(kind, capsys):
    assert run_cli("tool", _run, _parser(), ["--fail", kind]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("tool: error:")]
    assert len(lines) == 1
    assert "Traceback" not in err
    assert "tool: warning: something odd" in err  # the message, not a source line
    assert "warnings.warn" not in err


def test_debug_shows_the_traceback(capsys):
    assert run_cli("tool", _run, _parser(), ["--fail", "usage", "--debug"]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_a_bug_is_not_disguised_as_a_user_mistake():
    with pytest.raises(KeyError):
        run_cli("tool", _run, _parser(), ["--fail", "bug"])


def test_success_is_0():
    assert run_cli("tool", _run, _parser(), []) == 0


def test_check_output_file(tmp_path):
    with pytest.raises(UsageError, match="is a folder"):
        check_output_file(tmp_path)
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    with pytest.raises(UsageError, match="is a file, not a folder"):
        check_output_file(blocker / "sub" / "out.json")
    with pytest.raises(UsageError, match="--overwrite"):
        check_output_file(blocker, overwrite=False)
    assert check_output_file(tmp_path / "new" / "out.json") == tmp_path / "new" / "out.json"
    assert not (tmp_path / "new").exists()  # checking creates nothing
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(UsageError, match="not writable"):
            check_output_file(locked / "out.json")


def test_check_output_dir_refuses_a_foreign_folder(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "precious.txt").write_text("data")
    with pytest.raises(UsageError, match="not written by this tool"):
        check_output_dir(theirs, marker="report.json")
    assert check_output_dir(theirs, marker="report.json", overwrite=True) == theirs
    ours = tmp_path / "ours"
    ours.mkdir()
    (ours / "report.json").write_text("{}")
    assert check_output_dir(ours, marker="report.json") == ours
    (tmp_path / "empty").mkdir()
    assert check_output_dir(tmp_path / "empty", marker="report.json")
    with pytest.raises(UsageError, match="is a file"):
        check_output_dir(theirs / "precious.txt", marker="report.json")


def test_atomic_save_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = atomic_write_text(tmp_path / "r.json", "old")

    def broken(tmp):
        tmp.write_text("half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        atomic_save(target, broken)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]  # no temp left behind


def test_one_conventions_module_light_and_shared_by_models():
    """models/ and the export command use claravid/infra/cli.py (no drifted copy); importing it
    pulls in nothing heavy."""
    code = (
        "import sys, claravid.infra.cli\n"
        "print([m for m in ('cv2', 'albumentations', 'torch') if m in sys.modules])\n"
        "import claravid.eval.export_cli as e, claravid.models.checkpoint as c\n"
        "from claravid.infra import cli\n"
        "assert e.run_cli is cli.run_cli and c.atomic_save is cli.atomic_save\n"
        "import importlib.util\n"
        "assert importlib.util.find_spec('claravid.models.cli') is None\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_atomic_writes_respect_the_umask(umask, mode, tmp_path):
    from claravid.models import build_model, save_checkpoint

    old = os.umask(umask)
    try:
        text = atomic_write_text(tmp_path / "report.json", "{}")
        model = build_model("dinov2_vits14", 2, backbone_kwargs={"embed_dim": 8, "depth": 4,
                            "num_heads": 1}, layers=[0, 1, 2, 3], features=4,
                            out_channels=[4, 4, 4, 4])  # fmt: skip
        ckpt = save_checkpoint(model, tmp_path / "m.pt")
    finally:
        os.umask(old)
    # What open(path, "w") gives: 0666 minus the umask, as stat shows it.
    assert stat.S_IMODE(text.stat().st_mode) == mode
    assert stat.S_IMODE(ckpt.stat().st_mode) == mode


def _numbers_parser():
    parser = argparse.ArgumentParser(prog="tool")
    parser.add_argument("--window", type=positive_int)
    parser.add_argument("--tolerance", type=positive_float)
    return parser


@pytest.mark.parametrize("argv", [["--window", "0"], ["--tolerance", "-1"], ["--nope"]])
def test_argparse_mistakes_are_one_line_not_the_usage(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        run_cli("tool", lambda a: 0, _numbers_parser(), argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("tool: error: ") and "usage:" not in err
    assert argv[0] in err  # names the argument that was wrong


def test_multi_line_messages_become_one_line(capsys):
    def run(args):
        raise ValueError("first part\nsecond part")

    assert run_cli("tool", run, _parser(), []) == 2
    assert capsys.readouterr().err.strip() == "tool: error: first part; second part"


@pytest.mark.parametrize(
    ("text", "size"), [("640x480", (640, 480)), ("630", (630, 630)), (" 32X24", (32, 24))]
)
def test_a_size_is_width_x_height_or_one_number_for_a_square(text, size):
    assert parse_size(text) == size


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("0x48", "width and height must be positive, got '0x48'"),
        ("-14", "width and height must be positive"),
        ("64x", "expected WxH (width x height, e.g. 640x480) or N for N x N, got '64x'"),
        ("1x2x3", "expected WxH"),
        ("64*48", "expected WxH"),
        ("", "expected WxH"),
    ],
)
def test_bad_sizes(text, match):
    with pytest.raises(argparse.ArgumentTypeError, match=re.escape(match)):
        parse_size(text)


def test_a_window_is_given_width_x_height_and_a_non_square_one_says_how_it_reads(capsys):
    parser = argparse.ArgumentParser(prog="tool")
    parser.add_argument("--window", type=window_size)
    seen = []
    assert run_cli("tool", seen.append, parser, ["--window", "28"]) == 0
    assert seen[0].window == (28, 28) and capsys.readouterr().err == ""
    assert run_cli("tool", seen.append, parser, ["--window", "56x42"]) == 0
    assert seen[1].window == (42, 56)  # (height, width), the order of the tensors
    err = capsys.readouterr().err.strip()
    assert err == (
        "tool: warning: window size 56x42 is read as width 56 x height 42 (WxH, like every size "
        "flag; claravid 0.1 read --window and --stride as HxW)"
    )


def test_progress_switch_has_one_meaning_and_two_spellings():
    parser = argparse.ArgumentParser()
    add_progress_flag(parser)
    assert parser.parse_args([]).no_progress is False
    assert parser.parse_args(["--no-progress"]).no_progress is True
    assert parser.parse_args(["--quiet"]).no_progress is True


def test_workers_default_to_0_and_refuse_negatives(capsys):
    parser = argparse.ArgumentParser(prog="tool")
    add_workers_flag(parser, "decoding")
    assert parser.parse_args([]).workers == 0
    assert parser.parse_args(["--workers", "3"]).workers == 3
    with pytest.raises(SystemExit) as info:
        run_cli("tool", lambda a: 0, parser, ["--workers", "-1"])
    assert info.value.code == 2
    assert capsys.readouterr().err.strip() == (
        "tool: error: argument --workers: expected an integer >= 0, got '-1' (see tool --help)"
    )


def test_given_once():
    names = {"flag": "-o", "metavar": "OUT", "what": "the output folder"}
    assert given_once("a", None, **names) == "a"
    assert given_once(None, "b", **names) == "b"
    with pytest.raises(UsageError, match="the output folder given twice, as OUT and as -o"):
        given_once("a", "b", **names)
    with pytest.raises(UsageError, match=re.escape("give the output folder: -o OUT (or OUT")):
        given_once(None, None, **names)

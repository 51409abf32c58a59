"""The command-line conventions every console script shares (claravid.infra.cli)."""

import argparse
import re
import warnings

import pytest

from claravid.infra.cli import (
    UsageError,
    add_debug_flag,
    add_progress_flag,
    add_workers_flag,
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


def test_one_conventions_module_shared_by_models():
    """models/ and the export command use claravid/infra/cli.py and files.py (no drifted copy);
    that importing them pulls in nothing heavy is a claim of tests/claravid/test_imports.py's
    probe."""
    import importlib.util

    import claravid.eval.cli.export as e
    import claravid.models.checkpoint as c
    from claravid.infra import cli, files

    assert e.run_cli is cli.run_cli and c.atomic_save is files.atomic_save
    assert importlib.util.find_spec("claravid.models.cli") is None


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


def test_a_window_is_given_width_x_height(capsys):
    parser = argparse.ArgumentParser(prog="tool")
    parser.add_argument("--window", type=window_size)
    seen = []
    assert run_cli("tool", seen.append, parser, ["--window", "28"]) == 0
    assert seen[0].window == (28, 28) and capsys.readouterr().err == ""
    assert run_cli("tool", seen.append, parser, ["--window", "56x42"]) == 0
    assert seen[1].window == (42, 56)  # (height, width), the order of the tensors
    assert capsys.readouterr().err == ""


def test_progress_switch():
    parser = argparse.ArgumentParser()
    add_progress_flag(parser)
    assert parser.parse_args([]).no_progress is False
    assert parser.parse_args(["--no-progress"]).no_progress is True


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

"""Every console script spells the shared flags the same way, with the same help
(claravid.infra.cli), and refuses a bad value of one in one line, exit 2.

Parsed (or refused before any work), not run: what each flag then does is tested with its
command.
"""

import re

import pytest

from claravid import synth
from claravid.data import cache_cli
from claravid.dsp import cli as dsp
from claravid.eval.cli import evaluate, predict
from claravid.eval.cli import export as export_cli
from claravid.infra.cli import SHARED_HELP
from claravid.synth import demo
from claravid.train import cli as train

# Each command's parser and the arguments it needs besides the ones under test.
MODULES = {
    "claravid-synth": (synth, []),
    "claravid-cache": (cache_cli, ["--data", "ROOT"]),
    "claravid-demo": (demo, []),
    "claravid-dsp": (dsp, []),
    "claravid-export": (export_cli, ["--checkpoint", "m.pt"]),
    "claravid-eval": (evaluate, ["--checkpoint", "m.pt", "-o", "r"]),
    "claravid-predict": (predict, ["a.jpg"]),
    "claravid-train": (train, ["--config", "demo"]),
}
EVERYWHERE = ("--output",)
#: The shared flags (besides -o/--output) each command has: one spelling, one help text.
SHARED = {
    "claravid-synth": ("--missions", "--altitude", "--direction"),
    "claravid-cache": ("--data", "--missions", "--altitude", "--direction"),
    "claravid-demo": (),
    "claravid-dsp": ("--data",),
    "claravid-export": ("--checkpoint",),  # no --precision: the file's number format is --dtype
    "claravid-eval": ("--data", "--checkpoint", "--missions", "--altitude", "--direction",
                      "--window", "--stride", "--scale", "--batch-size", "--statistics",
                      "--device", "--precision"),
    "claravid-predict": ("--checkpoint", "--window", "--stride", "--scale", "--batch-size",
                         "--statistics", "--device", "--precision"),
    "claravid-train": ("--data", "--precision"),
}  # fmt: skip
COMMANDS = {name: (module.build_parser, needed) for name, (module, needed) in MODULES.items()}
WITH_PROGRESS = list(COMMANDS)  # export shows no bar: its --no-progress leaves out the numbers
WITH_WORKERS = [
    "claravid-cache",
    "claravid-demo",
    "claravid-dsp",
    "claravid-eval",
    "claravid-predict",
    "claravid-synth",
]


def _parse(command, *argv):
    build, needed = COMMANDS[command]
    return build().parse_args([*needed, *argv])


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_that_writes_takes_o_and_output(command):
    short = _parse(command, "-o", "x y")
    long = _parse(command, "--output", "x y")
    assert str(short.output) == str(long.output) == "x y"


@pytest.mark.parametrize("command", WITH_PROGRESS)
def test_no_progress_is_one_switch(command):
    assert _parse(command, "-o", "x").no_progress is False
    assert _parse(command, "-o", "x", "--no-progress").no_progress is True


REMOVED = [  # spellings of before 0.2 that are gone, not aliases
    ("claravid-synth", ["--quiet"], "--quiet"),
    ("claravid-dsp", ["--quiet"], "--quiet"),
    ("claravid-eval", ["--no-amp"], "--no-amp"),
    ("claravid-export", ["--height", "28"], "--height 28"),
    ("claravid-export", ["--width", "28"], "--width 28"),
    ("claravid-export", ["m.pt"], "m.pt"),  # the checkpoint is --checkpoint
]


@pytest.mark.parametrize(("command", "argv", "named"), REMOVED)
def test_removed_spellings_are_one_line_usage_errors(command, argv, named, capsys):
    module, needed = MODULES[command]
    with pytest.raises(SystemExit) as info:  # argparse's error, before any work
        module.main([*needed, "-o", "x", *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"unrecognized arguments: {named}" in err[0], err


@pytest.mark.parametrize("command", WITH_WORKERS)
def test_workers_mean_the_same_everywhere(command):
    assert _parse(command, "-o", "x").workers == 0
    assert _parse(command, "-o", "x", "--workers", "3").workers == 3
    action = next(a for a in COMMANDS[command][0]()._actions if a.dest == "workers")
    assert action.help.startswith("worker processes for ")
    assert action.help.endswith(" (default 0: all in this process)")


def test_train_workers_are_the_data_loader_workers():
    """``claravid-train --workers N`` is ``data.num_workers=N``; without it the config's."""
    from claravid.train.cli import overrides

    assert _parse("claravid-train").workers is None
    assert overrides(_parse("claravid-train", "--workers", "3")) == ["data.num_workers=3"]
    action = next(a for a in train.build_parser()._actions if a.dest == "workers")
    assert action.help.startswith("worker processes for ")


@pytest.mark.parametrize(
    ("command", "flag", "value", "parsed"),
    [
        ("claravid-synth", "--size", "64x48", (64, 48)),  # (width, height)
        ("claravid-demo", "--size", "64x48", (64, 48)),
        ("claravid-export", "--size", "64x48", (64, 48)),
        ("claravid-export", "--size", "630", (630, 630)),
        ("claravid-eval", "--window", "630", (630, 630)),
        ("claravid-eval", "--window", "56x42", (42, 56)),  # (height, width) for the windows
        ("claravid-eval", "--stride", "28x14", (14, 28)),
        ("claravid-predict", "--window", "56x42", (42, 56)),
        ("claravid-predict", "--stride", "28", (28, 28)),
    ],
)
def test_one_size_syntax(command, flag, value, parsed):
    assert getattr(_parse(command, "-o", "x", flag, value), flag[2:]) == parsed


@pytest.mark.parametrize("command", ["claravid-export", "claravid-eval", "claravid-predict"])
def test_the_checkpoint_is_given_with_checkpoint(command):
    assert str(_parse(command, "-o", "x", "--checkpoint", "m.pt").checkpoint) == "m.pt"


def _shared_flags(command):
    """``{flag: help}`` of the shared flags a command's parser has."""
    helps = {}
    for action in COMMANDS[command][0]()._actions:
        for flag in action.option_strings:
            if flag in SHARED_HELP:
                helps[flag] = action.help
    return helps


@pytest.mark.parametrize("command", COMMANDS)
def test_the_shared_flags_have_one_help_text_everywhere(command):
    """Each command has the shared flags it should, each with the one help text, and its
    ``--help`` shows that text."""
    helps = _shared_flags(command)
    assert sorted(helps) == sorted([*EVERYWHERE, *SHARED[command]])
    text = " ".join(COMMANDS[command][0]().format_help().split())
    for flag, help in helps.items():
        assert help == SHARED_HELP[flag], (command, flag)
        assert " ".join(help.split()) in text, (command, flag)


def test_every_shared_flag_is_used_by_two_commands_or_more():
    counts = {flag: sum(flag in (*EVERYWHERE, *s) for s in SHARED.values()) for flag in SHARED_HELP}
    assert min(counts.values()) >= 2, counts


#: A bad value of each shared flag that argparse refuses, and what the line says.
BAD_VALUES = {
    "--window": ("0x630", "width and height must be positive, got '0x630'"),
    "--stride": ("wide", "expected WxH (width x height, e.g. 640x480) or N for N x N"),
    "--scale": ("0", "expected a finite number > 0, got '0'"),
    "--batch-size": ("-2", "expected a positive integer, got '-2'"),
    "--precision": ("fp8", "invalid choice: 'fp8' (choose from "),
    "--statistics": ("lvd1689m", "invalid choice: 'lvd1689m' (choose from "),
}


@pytest.mark.parametrize(
    ("command", "flag"),
    [(c, f) for c, flags in SHARED.items() for f in flags if f in BAD_VALUES],
)
def test_a_bad_value_of_a_shared_flag_is_one_line_exit_2(command, flag, capsys):
    module, needed = MODULES[command]
    value, message = BAD_VALUES[flag]
    with pytest.raises(SystemExit) as info:  # argparse's error, before any work
        module.main([*needed, "-o", "x", flag, value])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {flag}: {message}" in err[0], err


#: What each selecting command needs to reach its selection check (nothing is read before it).
SELECTING = {
    "claravid-synth": [],
    "claravid-cache": ["--data", "R"],
    "claravid-eval": ["--predictions", "P"],
}


@pytest.mark.parametrize("command", SELECTING)
def test_selection_flags_are_one_comma_separated_list(command, capsys, tmp_path):
    """``--missions rural_1,urban_1`` everywhere; ``--missions rural_1 urban_1`` and an empty
    list are one-line usage errors everywhere, not a second spelling some commands accept."""
    main = MODULES[command][0].main
    needed = [*SELECTING[command], "-o", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as info:
        main([*needed, "--missions", "rural_1", "urban_1"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unrecognized arguments: urban_1" in err[0]
    for flag, example in (("--missions", "rural_1,urban_2"), ("--direction", "h")):
        assert main([*needed, flag, " , "]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"{command}: error: {flag} is empty; give e.g. {flag} {example}"]
    assert not (tmp_path / "out").exists()


def test_train_flags_are_config_keys():
    """``claravid-train --data``, ``-o``, ``--precision``: ``data.root``, ``out_dir``,
    ``train.precision`` (the paths as given, quoted for YAML)."""
    from claravid.train.cli import overrides

    args = _parse("claravid-train", "--data", "/d/x y", "-o", "r", "--precision", "bf16")
    assert overrides(args) == ["data.root='/d/x y'", "out_dir='r'", "train.precision=bf16"]


def _runnable_modules() -> list[str]:
    """Every ``python -m`` path the package offers: modules with a ``__main__`` guard and
    packages with a ``__main__.py``."""
    import importlib.util
    from pathlib import Path

    names = []
    for package in ("claravid", "claravid.eval", "claravid.train", "claravid.models"):
        folder = Path(importlib.util.find_spec(package).origin).parent
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if package == "claravid" and parts[0] in ("eval", "train", "models", "configs"):
                continue  # a link tree's copies: walked under their own names
            text = path.read_text()
            if path.name == "__main__.py":
                names.append(".".join([package, *parts[:-1]]))
            elif 'if __name__ == "__main__":' in text:
                names.append(".".join([package, *parts]))
    return names


def test_every_python_m_path_runs(capsys, monkeypatch):
    """``python -m claravid.eval --help`` and every other runnable module print their usage
    (the former paths' alias crashed on ``python -m``)."""
    import runpy
    import sys
    import warnings

    modules = _runnable_modules()
    assert {"claravid.eval", "claravid.train", "claravid.data.cache_cli"} <= set(modules)
    for name in modules:
        monkeypatch.setattr(sys, "argv", [name, "--help"])
        with warnings.catch_warnings(), pytest.raises(SystemExit) as info:
            # Already imported by this test session: runpy says so, harmlessly.
            warnings.filterwarnings("ignore", "'.*' found in sys.modules", RuntimeWarning)
            runpy.run_module(name, run_name="__main__", alter_sys=True)
        assert info.value.code == 0, name
        assert capsys.readouterr().out.startswith("usage: claravid-"), name


def test_docs_show_one_table_of_the_shared_flags():
    """docs/cli.md's table of shared flags states each flag's help, as the commands print it."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "cli.md").read_text(encoding="utf-8")
    section = text.split("## Shared flags", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(?:-o/)?(--[a-z-]+)[^`]*` \| ([^|]+) \|", section, re.M)
    assert dict((flag, meaning.strip()) for flag, meaning in rows) == SHARED_HELP

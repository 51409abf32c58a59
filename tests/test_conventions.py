"""Every console script spells the shared flags the same way (issue 12 §3, claravid.infra.cli).

Parsed, not run: what each flag then does is tested with its command.
"""

import pytest

from claravid import synth
from claravid.data import cache_cli
from claravid.dsp import cli as dsp
from claravid.eval import cli as evaluate
from claravid.eval import export_cli, predict
from claravid.synth import demo
from claravid.train import cli as train

# Each command's parser and the arguments it needs besides the ones under test.
MODULES = {
    "claravid-synth": (synth, []),
    "claravid-cache": (cache_cli, ["ROOT"]),
    "claravid-demo": (demo, []),
    "claravid-dsp": (dsp, []),
    "claravid-export": (export_cli, ["--checkpoint", "m.pt"]),
    "claravid-eval": (evaluate, []),
    "claravid-predict": (predict, ["a.jpg"]),
    "claravid-train": (train, ["--config", "demo"]),
}
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


SELECTING = {  # the commands that select ClaraVid frames by flags, and how each reads them
    "claravid-cache": (cache_cli.main, cache_cli.selection_flags),
    # claravid-eval hands the flags to DataChoice, which splits them (the API's rule too).
    "claravid-eval": (evaluate.main, lambda args: evaluate._data_choice(args).selection),
}


@pytest.mark.parametrize("command", SELECTING)
def test_selection_flags_are_one_comma_separated_list(command, capsys):
    """``--missions rural_1,urban_1`` everywhere; ``--missions rural_1 urban_1`` is a one-line
    usage error everywhere, not a second spelling some commands accept."""
    main, selection = SELECTING[command]
    args = _parse(command, "--missions", "rural_1,urban_1", "--altitude", "high,low",
                  "--direction", "v")  # fmt: skip
    assert selection(args) == {
        "missions": ["rural_1", "urban_1"], "altitude": ["high", "low"], "direction": ["v"]
    }  # fmt: skip
    needed = COMMANDS[command][1]
    with pytest.raises(SystemExit) as info:
        main([*needed, "-o", "x", "--missions", "rural_1", "urban_1"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unrecognized arguments: urban_1" in err[0]


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

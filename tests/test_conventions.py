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
COMMANDS = {
    "claravid-synth": (synth.build_parser, []),
    "claravid-cache": (cache_cli.build_parser, ["ROOT"]),
    "claravid-demo": (demo.build_parser, []),
    "claravid-dsp": (dsp.build_parser, []),
    "claravid-export": (export_cli.build_parser, []),
    "claravid-eval": (evaluate.build_parser, []),
    "claravid-predict": (predict.build_parser, ["a.jpg"]),
    "claravid-train": (train.build_parser, ["--config", "demo"]),
}
WITH_PROGRESS = list(COMMANDS)  # export shows no bar: its --quiet leaves out the check's numbers
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
def test_no_progress_and_quiet_are_one_switch(command):
    assert _parse(command, "-o", "x").no_progress is False
    assert _parse(command, "-o", "x", "--no-progress").no_progress is True
    assert _parse(command, "-o", "x", "--quiet").no_progress is True


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
@pytest.mark.filterwarnings("ignore:window size")  # how a non-square window reads: test_cli.py
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

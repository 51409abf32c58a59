"""Conventions shared by every console script (see docs/cli.md#conventions).

Exit 0 on success; 1 when the work ran but some inputs could not be used (listed in the output);
2 for a user's mistake, printed as one line that says what was wrong and what to do, never a
traceback (``--debug`` or ``CLARAVID_DEBUG=1`` shows it). Output paths are checked before long
work starts and written atomically; nothing the tool did not write is replaced without
``--overwrite`` (:mod:`claravid.infra.files`).

The same concept is the same flag, with the same help, on every command that has it, made by
one builder here: ``--data`` (where the images are), ``-o/--output`` (what the command writes),
``--checkpoint``, the ClaraVid selection ``--missions``/``--altitude``/``--direction`` (comma
lists), the windows ``--window``/``--stride``/``--scale``/``--batch-size``, the test-time
augmentation ``--tta``/``--tta-scales``/``--flip``/``--tta-size``, ``--device``,
``--precision``, ``--workers``, ``--no-progress`` and ``--debug``. A size is ``WxH`` (width x
height) or ``N`` for a square (`parse_size`).

A console script is a thin ``main`` over importable functions::

    def main(argv=None) -> int:
        return run_cli("claravid-eval", _run, build_parser(), argv)
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn, Protocol

from claravid.infra.precision import PRECISIONS

EXIT_OK = 0
EXIT_PARTIAL = 1  # the work ran, some inputs could not be used (listed)
EXIT_FAILED = 1  # the work ran and its result failed a check (nothing written)
EXIT_USAGE = 2


class FlagGroup(Protocol):
    """What flags are added to: a parser, or one of its argument groups."""

    def add_argument(self, *name_or_flags: str, **kwargs: Any) -> argparse.Action: ...


class UsageError(Exception):
    """A user's mistake (bad argument, missing or foreign input, unusable output path)."""


#: What a command line reports as a user's mistake (exit 2, one line). Our own validation raises
#: ValueError/FileNotFoundError subclasses with messages written for the user.
USER_ERRORS: tuple[type[BaseException], ...] = (UsageError, OSError, ValueError)


def add_debug_flag(parser: argparse.ArgumentParser) -> None:
    """``--debug``: show the Python traceback of an error (also ``CLARAVID_DEBUG=1``)."""
    parser.add_argument(
        "--debug", action="store_true", help="show the Python traceback of an error"
    )


def add_progress_flag(parser: FlagGroup, help: str = "no progress bar") -> None:
    """``--no-progress``: no progress bar.

    Sets ``args.no_progress``; ``claravid-train``'s flag means ``log.progress=false``;
    ``claravid-export``, which shows no bar, leaves out the check's numbers (``help`` says so).
    """
    parser.add_argument("--no-progress", action="store_true", help=help)


def add_workers_flag(parser: FlagGroup, work: str) -> None:
    """``--workers N``: ``work`` in N worker processes; 0, the default, runs it in this one."""
    parser.add_argument(
        "--workers",
        type=non_negative_int,
        default=0,
        metavar="N",
        help=f"worker processes for {work} (default 0: all in this process)",
    )


#: The help of each shared flag, one text per concept (``docs/cli.md`` shows them in one table).
SHARED_HELP = {
    "--data": "where the images are: a ClaraVid or UAVid root, or a folder of images",
    "--output": "what the command writes (checked before the work starts)",
    "--checkpoint": "a model checkpoint written by claravid-train (models.save_checkpoint)",
    "--missions": "ClaraVid missions, comma-separated: keys, aliases or folder names, e.g. "
    "rural_1,urban_2",
    "--altitude": "ClaraVid altitudes, comma-separated: low, mid, high, e.g. low,mid",
    "--direction": "ClaraVid flight directions, comma-separated: h, v, e.g. h",
    "--window": "sliding window, WxH or N for N x N (default: the model file's, else the "
    "model's natural size: 630 for patches of 14, 640 for 16)",
    "--stride": "step between windows, WxH or N (default: the model file's for its window, "
    "else two thirds of the window)",
    "--scale": "resize the images by this factor first (default: the model file's, else 1; the "
    "paper reports at 0.5)",
    "--batch-size": "windows per forward pass (default: the model file's, else 4)",
    "--device": "cpu, cuda or cuda:N (default: cuda when available)",
    "--statistics": "input statistics of an ONNX file exported elsewhere (it records none): "
    "imagenet (DINOv2, DINOv3 web weights) or sat493m (DINOv3 _sat weights)",
    "--precision": "autocast of a PyTorch model: auto (the default: float32 on a CPU, bf16 on a "
    "GPU that supports it, else fp16), fp32, bf16 or fp16",
    "--tta": "test-time augmentation as a published protocol runs it: dinov3 (ratios 0.9 to 1.1 "
    "and the mirror, the DINOv3 size rule), mmseg (ratios 0.5 to 1.75 and the mirror, "
    "mmsegmentation's), or none (default: the model file's, else none)",
    "--tta-scales": "test-time augmentation ratios, comma-separated, e.g. 0.9,0.95,1,1.05,1.1 "
    "(with --tta: instead of the preset's)",
    "--flip": "test-time augmentation: also run each copy mirrored left-right",
    "--tta-size": "S of the dinov3 size rule, the small side at ratio 1 (the official "
    "evaluation uses its window, 512 or 896; default: the image's small side at --scale)",
}


def _add(parser: Any, *names: str, **kwargs: Any) -> None:
    """``add_argument`` with the shared help of ``names[-1]`` (a parser or an argument group)."""
    parser.add_argument(*names, help=SHARED_HELP[names[-1]], **kwargs)


def add_data_flag(parser: Any, *, required: bool = False) -> None:
    """``--data PATH``: where the images are (``args.data``, a `Path`)."""
    _add(parser, "--data", type=Path, metavar="PATH", required=required)


def add_output_flag(parser: Any, *, metavar: str = "DIR", required: bool = False) -> None:
    """``-o/--output``: what the command writes (``args.output``, a `Path`); ``metavar`` names
    its kind (``DIR``, ``FILE``, ``JSON``)."""
    _add(parser, "-o", "--output", type=Path, metavar=metavar, required=required)


def add_checkpoint_flag(parser: Any, *, required: bool = False) -> None:
    """``--checkpoint CKPT``: a model checkpoint (``args.checkpoint``, a `Path`)."""
    _add(parser, "--checkpoint", type=Path, metavar="CKPT", required=required)


def add_selection_flags(parser: Any) -> None:
    """``--missions``, ``--altitude``, ``--direction``: one comma-separated list each, kept as
    typed (`selection_names` splits them, with the message the Python API gives; the names are
    checked where the frames are chosen)."""
    for flag in ("--missions", "--altitude", "--direction"):
        _add(parser, flag, metavar="LIST")


def add_window_flags(parser: Any) -> None:
    """``--window``, ``--stride`` (``(height, width)``, `window_size`), ``--scale`` and
    ``--batch-size``: how images are cut into windows; unset, None (the model file's record,
    else the defaults)."""
    _add(parser, "--window", type=window_size, metavar="WxH")
    _add(parser, "--stride", type=window_size, metavar="WxH")
    _add(parser, "--scale", type=positive_float, metavar="S")
    _add(parser, "--batch-size", type=positive_int, metavar="N")


def add_tta_flags(parser: Any) -> None:
    """``--tta {dinov3,mmseg,none}``, ``--tta-scales LIST`` (`ratio_list`), ``--flip`` and
    ``--tta-size S``: test-time augmentation; all unset: None (the model file's record, else
    none). ``claravid.eval.inference.augment.tta_from_flags`` turns them into settings."""
    tta = ("dinov3", "mmseg", "none")
    _add(parser, "--tta", choices=tta, metavar="{" + ",".join(tta) + "}")
    _add(parser, "--tta-scales", type=ratio_list, metavar="LIST")
    _add(parser, "--flip", action="store_true")
    _add(parser, "--tta-size", type=positive_int, metavar="S")


def ratio_list(text: str) -> tuple[float, ...]:
    """argparse type for comma-separated ratios > 0 (``0.9,1,1.1``)."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated ratios such as 0.9,1,1.1, got {text!r}"
        ) from None
    if not values or not all(math.isfinite(v) and 0 < v <= 8 for v in values):
        raise argparse.ArgumentTypeError(
            f"expected comma-separated ratios in (0, 8] such as 0.9,1,1.1, got {text!r}"
        )
    return values


def add_statistics_flag(parser: Any, names: Iterable[str]) -> None:
    """``--statistics NAME``: the input statistics of a model file that records none, one of
    ``names`` (``claravid.models.backbones.specs.NAMED_STATISTICS``; unset: None)."""
    choices = tuple(names)
    _add(parser, "--statistics", choices=choices, metavar="{" + ",".join(choices) + "}")


def add_device_flag(parser: Any) -> None:
    """``--device DEV`` (checked with `check_device` before the work)."""
    _add(parser, "--device", metavar="DEV")


def add_precision_flag(parser: Any) -> None:
    """``--precision P``, one of `PRECISIONS` (unset: None, which means ``auto``)."""
    _add(parser, "--precision", choices=PRECISIONS, metavar="{" + ",".join(PRECISIONS) + "}")


#: An example of each selection flag, for the message about an empty one.
SELECTION_EXAMPLES = {"missions": "rural_1,urban_2", "altitude": "low,mid", "direction": "h"}


def selection_names(name: str, given: str | Sequence[str]) -> list[str]:
    """A selection's names: ``"rural_1,urban_2"`` (as typed) or a list -> ``["rural_1",
    "urban_2"]``, blank names dropped.

    Raises:
        ValueError: no name left (``--missions ,``).
    """
    items = given.split(",") if isinstance(given, str) else list(given)
    values = [str(v).strip() for v in items if str(v).strip()]
    if not values:
        raise ValueError(f"--{name} is empty; give e.g. --{name} {SELECTION_EXAMPLES[name]}")
    return values


def parse_size(text: str) -> tuple[int, int]:
    """argparse type for every size flag: ``WxH`` (width x height, ``640x480``) or ``N`` (N x N).

    Returns:
        ``(width, height)``.
    """
    parts = text.strip().lower().split("x")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2):
        raise argparse.ArgumentTypeError(
            f"expected WxH (width x height, e.g. 640x480) or N for N x N, got {text!r}"
        )
    if min(values) < 1:
        raise argparse.ArgumentTypeError(f"width and height must be positive, got {text!r}")
    return values[0], values[-1]


def window_size(text: str) -> tuple[int, int]:
    """`parse_size` for a sliding window or its stride, returned as ``(height, width)``, the
    order of the tensors and of ``WindowConfig``."""
    width, height = parse_size(text)
    return height, width


def positive_int(text: str) -> int:
    """argparse type for an integer > 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type for an integer >= 0 (a seed, a worker count)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type for a finite number > 0 (a tolerance, a scale)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def check_device(name: str | None, what: str = "--device") -> None:
    """Fail now, in one line, when ``name`` is not a device this PyTorch can use.

    ``None`` (choose automatically) always passes. torch is imported here, not at module import,
    so this module stays light for the console scripts' ``--help``.

    Raises:
        UsageError: an unknown device kind, CUDA on a PyTorch without CUDA (or no GPU), or a
            GPU index beyond the GPUs present.
    """
    if name is None:
        return
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise UsageError(f"{what} {name!r} is not a device; use cpu, cuda or cuda:N") from None
    if device.type == "cpu":
        return
    if device.type != "cuda":
        raise UsageError(f"{what} {name!r} is not supported; use cpu, cuda or cuda:N")
    if not torch.cuda.is_available():
        why = "this PyTorch has no CUDA" if torch.version.cuda is None else "no GPU is visible"
        raise UsageError(f"{what} {name!r}: {why}; use cpu (or leave it unset)")
    count = torch.cuda.device_count()
    if device.index is not None and device.index >= count:
        raise UsageError(
            f"{what} {name!r}: only {count} GPU(s) are visible (cuda:0..cuda:{count - 1})"
        )


def _one_line_usage_errors(parser: argparse.ArgumentParser) -> None:
    """argparse's own errors (a bad number, a missing flag) as one line, not usage + error."""
    prog = parser.prog

    def error(message: str) -> NoReturn:  # argparse's signature
        parser.exit(EXIT_USAGE, f"{prog}: error: {message} (see {prog} --help)\n")

    parser.error = error  # type: ignore[method-assign]  # replaced on purpose: one line, exit 2


def _debug(argv: list[str]) -> bool:
    return "--debug" in argv or os.environ.get("CLARAVID_DEBUG", "") not in ("", "0")


@contextlib.contextmanager
def short_warnings(prog: str) -> Iterator[None]:
    """Print warnings to stderr as ``prog: warning: message``, not as Python source lines."""
    original = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{prog}: warning: {message}", file=sys.stderr)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = original


def worker_message(exc: BaseException) -> str:
    """An error's message; for one that torch's DataLoader re-raised from a worker process, the
    original message alone.

    torch rebuilds a worker's error as ``type(error)(text)``, where ``text`` is "Caught X in
    DataLoader worker process N." followed by the worker's whole traceback, whose last entry,
    ``module.X: message``, is what the user needs (the traceback is for ``--debug``).
    """
    message = str(exc)
    if not message.startswith(f"Caught {type(exc).__name__} ") or (
        "\nOriginal Traceback" not in message
    ):
        return message
    cls = type(exc)
    prefixes = (f"{cls.__module__}.{cls.__qualname__}: ", f"{cls.__qualname__}: ")
    lines = message.splitlines()
    for i in range(len(lines) - 1, 0, -1):  # the last one: the error raised, not its causes
        for prefix in prefixes:
            if lines[i].startswith(prefix):
                return "\n".join([lines[i][len(prefix) :], *lines[i + 1 :]])
    return message


def _leave_process_group() -> None:
    """Under torchrun, tear down the process group the command made while the interpreter is
    whole: left to interpreter shutdown, gloo's threads can abort the process after the work is
    done ("terminate called without an active exception"). Nothing to do unless the command
    imported the distributed helpers."""
    distributed = sys.modules.get("claravid.infra.distributed")
    if distributed is not None:
        distributed.shutdown()


def run_cli(
    prog: str,
    run: Callable[[argparse.Namespace], int | None],
    parser: argparse.ArgumentParser,
    argv: list[str] | None = None,
    user_errors: tuple[type[BaseException], ...] = (),
) -> int:
    """Parse ``argv``, call ``run(args)`` and map errors to the exit-code conventions.

    ``user_errors`` adds exception types (beyond `USER_ERRORS`) that mean the user's input was
    wrong; anything else is a bug and keeps its traceback. Returns the exit status (argparse's
    own errors exit 2 through ``SystemExit``, as one line too).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    _one_line_usage_errors(parser)
    debug = _debug(argv)
    with short_warnings(prog):
        args = parser.parse_args(argv)  # inside: a flag's warning reads like the others
        try:
            code = run(args)
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            return 130
        except (*USER_ERRORS, *user_errors) as exc:
            if debug:
                traceback.print_exc()
            message = worker_message(exc) or exc.__class__.__name__
            if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in message:
                message = f"{message}: {exc.filename}"
            # One line: a multi-line message (a list of mismatched keys) is joined.
            message = "; ".join(line.strip() for line in message.splitlines() if line.strip())
            print(f"{prog}: error: {message}", file=sys.stderr)
            return EXIT_USAGE
        finally:
            _leave_process_group()
    return EXIT_OK if code is None else int(code)

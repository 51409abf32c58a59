"""The command-line conventions (ARCHITECTURE.md) for the console scripts of ``models/``.

Why a copy: ``claravid/cli.py`` holds these conventions for the data side, but ``models/`` and
``claravid/`` never import each other (the datasets give tensors, the segmenter takes tensors), so
``claravid-export`` gets this minimal equivalent: exit 2 and one line for a user's mistake
(``--debug`` or ``CLARAVID_DEBUG=1`` shows the traceback), warnings printed as
``prog: warning: message``, and output paths checked before the work. Keep the two in step.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


class UsageError(Exception):
    """A user's mistake (bad argument, missing or foreign input, unusable output path)."""


def run_cli(
    prog: str,
    run: Callable[[argparse.Namespace], int | None],
    parser: argparse.ArgumentParser,
    argv: list[str] | None,
    user_errors: tuple[type[BaseException], ...] = (),
) -> int:
    """Parse ``argv``, call ``run(args)``; a user's mistake -> one line on stderr and exit 2.

    ``user_errors`` adds exception types (beyond UsageError, OSError, ValueError) that mean the
    user's input was wrong. Anything else is a bug and keeps its traceback.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    debug = getattr(args, "debug", False) or os.environ.get("CLARAVID_DEBUG", "") not in ("", "0")
    original = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{prog}: warning: {message}", file=sys.stderr)

    warnings.showwarning = show
    try:
        code = run(args)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except (UsageError, OSError, ValueError, *user_errors) as exc:
        if debug:
            traceback.print_exc()
        message = str(exc) or type(exc).__name__
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in message:
            message = f"{message}: {exc.filename}"
        # One line: multi-line messages (a list of mismatched keys) are joined.
        print(f"{prog}: error: {'; '.join(message.splitlines())}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        warnings.showwarning = original
    return EXIT_OK if code is None else int(code)


def add_debug_flag(parser: argparse.ArgumentParser) -> None:
    """``--debug``: show the Python traceback of an error (also ``CLARAVID_DEBUG=1``)."""
    parser.add_argument(
        "--debug", action="store_true", help="show the Python traceback of an error"
    )


def check_output_file(path: str | os.PathLike, what: str = "--output") -> Path:
    """Fail now, not after the work, when ``path`` cannot be written as a file (creates nothing)."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{what} {path} is a folder; give a file path inside it")
    anchor = path.parent
    while not anchor.exists() and anchor != anchor.parent:
        anchor = anchor.parent
    if not anchor.is_dir():
        raise UsageError(f"{what} {path} cannot be created: {anchor} is a file, not a folder")
    if not os.access(anchor, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path} cannot be written: {anchor} is not writable")
    if path.exists() and not os.access(path, os.W_OK):
        raise UsageError(f"{what} {path} exists and is not writable")
    return path


def positive_int(text: str) -> int:
    """argparse type: an integer > 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value

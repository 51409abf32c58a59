"""Conventions shared by every console script (see ARCHITECTURE.md, "Command-line conventions").

Exit 0 on success; 1 when the work ran but some inputs could not be used (listed in the output);
2 for a user's mistake, printed as one line that says what was wrong and what to do, never a
traceback (``--debug`` or ``CLARAVID_DEBUG=1`` shows it). Output paths are checked before long
work starts and written atomically; nothing the tool did not write is replaced without
``--overwrite``.

A console script is a thin ``main`` over importable functions::

    def main(argv=None) -> int:
        return run_cli("claravid-eval", _run, build_parser(), argv)
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import traceback
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

EXIT_OK = 0
EXIT_PARTIAL = 1
EXIT_USAGE = 2


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


def run_cli(
    prog: str,
    run: Callable[[argparse.Namespace], int | None],
    parser: argparse.ArgumentParser,
    argv: list[str] | None = None,
) -> int:
    """Parse ``argv``, call ``run(args)`` and map errors to the exit-code conventions.

    Returns the exit status (argparse's own usage errors exit 2 through ``SystemExit``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    debug = _debug(argv)
    with short_warnings(prog):
        try:
            code = run(args)
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            return 130
        except USER_ERRORS as exc:
            if debug:
                traceback.print_exc()
            message = str(exc) or exc.__class__.__name__
            if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in message:
                message = f"{message}: {exc.filename}"
            print(f"{prog}: error: {message}", file=sys.stderr)
            return EXIT_USAGE
    return EXIT_OK if code is None else int(code)


def _first_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_output_file(
    path: str | os.PathLike, *, overwrite: bool = True, what: str = "output"
) -> Path:
    """Fail now, not after the work, if ``path`` cannot be written as a file.

    Args:
        path: the file to write.
        overwrite: whether an existing file may be replaced.
        what: how the message names it (``"--output"``).
    """
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{what} {path} is a directory; give a file path inside it")
    if path.exists() and not overwrite:
        raise UsageError(f"{what} {path} exists; pass --overwrite to replace it")
    anchor = _first_existing(path.parent)
    if not anchor.is_dir():
        raise UsageError(f"{what} {path} cannot be created: {anchor} is a file, not a folder")
    if not os.access(anchor, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path} cannot be written: {anchor} is not writable")
    return path


def check_output_dir(
    path: str | os.PathLike, *, marker: str, overwrite: bool = False, what: str = "output"
) -> Path:
    """Fail now if ``path`` cannot be the tool's output folder.

    A folder that exists, is not empty and holds no ``marker`` file (what this tool writes) is
    someone else's: refused unless ``overwrite``.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{what} {path} is a file; give a folder")
    if path.is_dir():
        foreign = any(path.iterdir()) and not (path / marker).exists()
        if foreign and not overwrite:
            raise UsageError(
                f"{what} {path} is not empty and was not written by this tool (no {marker}); "
                "choose a new folder or pass --overwrite"
            )
        if not os.access(path, os.W_OK | os.X_OK):
            raise UsageError(f"{what} {path} is not writable")
        return path
    anchor = _first_existing(path)
    if not anchor.is_dir():
        raise UsageError(f"{what} {path} cannot be created: {anchor} is a file, not a folder")
    if not os.access(anchor, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path} cannot be created: {anchor} is not writable")
    return path


def atomic_save(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a temp file beside ``path`` (same suffix), then rename it over.

    A crash at any moment leaves either the old file or the new one, never half a file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_save(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))

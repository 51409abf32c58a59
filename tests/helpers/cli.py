"""Running a console script's ``main`` in-process the way a shell sees it."""

from collections.abc import Callable


def exit_code(main: Callable[[list[str]], int], argv: list[str]) -> int:
    """``main(argv)``'s exit status, whether it returns it or argparse exits with it (an
    unknown flag, a missing argument)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)

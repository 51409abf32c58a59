"""Files the toolkit writes: output paths checked before the work, results written atomically.

Every command checks where it will write before long work starts (`check_output_file`,
`check_output_dir`), and never replaces what it did not write without ``--overwrite``: a folder
is recognised by a marker file the tool leaves. Results are written to a temporary file beside
the target and renamed over it (`atomic_save`, `atomic_write_text`), so a crash leaves the old
file or the new one, never half of one.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from claravid.infra.cli import UsageError


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
        raise UsageError(f"{what} {path} is a folder; give a file path inside it")
    if path.exists() and not overwrite:
        raise UsageError(f"{what} {path} exists; pass --overwrite to replace it")
    if path.exists() and not os.access(path, os.W_OK):
        raise UsageError(f"{what} {path} exists and is not writable")
    anchor = _first_existing(path.parent)
    if not anchor.is_dir():
        raise UsageError(f"{what} {path} cannot be created: {anchor} is a file, not a folder")
    if not os.access(anchor, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path} cannot be written: {anchor} is not writable")
    return path


def check_output_dir(
    path: str | os.PathLike,
    *,
    marker: str,
    overwrite: bool | None = False,
    what: str = "output",
) -> Path:
    """Fail now if ``path`` cannot be the tool's output folder.

    A folder that exists, is not empty and holds no ``marker`` file (what this tool writes) is
    someone else's: refused unless ``overwrite``. ``overwrite=None``: the tool has no
    ``--overwrite`` flag, so the message does not advise one.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{what} {path} is a file; give a folder")
    if path.is_dir():
        foreign = any(path.iterdir()) and not (path / marker).exists()
        if foreign and not overwrite:
            fix = "pass --overwrite" if overwrite is not None else "empty it"
            raise UsageError(
                f"{what} {path} is not empty and was not written by this tool (no {marker}); "
                f"choose a new folder or {fix}"
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


def current_umask() -> int:
    """The process's umask, read without changing it where the OS allows (Linux)."""
    with contextlib.suppress(OSError, ValueError), open("/proc/self/status") as status:
        for line in status:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)  # elsewhere: the classic read-by-setting, restored at once
    os.umask(mask)
    return mask


def atomic_save(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a temp file beside ``path`` (same suffix), then rename it over.

    A crash at any moment leaves either the old file or the new one, never half a file. The
    file gets the permissions a plain ``open(path, "w")`` would give (0666 minus the umask),
    not the temp file's private 0600: others may read reports and checkpoints on a shared
    machine when the umask says so.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_save(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


@contextlib.contextmanager
def output_lock(folder: str | os.PathLike, what: str = "--output") -> Iterator[None]:
    """Hold ``folder`` for one writer: a second command or call writing the same folder at the
    same time is refused instead of silently replacing the first one's results.

    The lock is an advisory ``flock`` on a hidden file beside the folder (the folder itself is
    replaced whole when written), released by the system when the holder exits, even killed.

    Raises:
        UsageError: another process holds the folder (naming it and its process id).
    """
    import fcntl

    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    path = folder.parent / f".{folder.name}.lock"
    handle = open(path, "a+")  # noqa: SIM115  (held open while the lock is)
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "?"
            raise UsageError(
                f"{what} {folder} is being written by another run (process {holder}): wait for "
                f"it to finish, or choose another {what}"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                path.unlink()
    finally:
        handle.close()

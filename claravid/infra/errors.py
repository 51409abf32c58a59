"""Errors that tell the user what was wrong and what to do about it.

Every error class of the toolkit can be rebuilt from its message alone, ``type(error)(message)``,
and survives pickling with its attributes: that is how an error crosses a process boundary
(``multiprocessing`` pickles it; torch's DataLoader rebuilds a worker's error as
``type(error)(text)``). A class whose constructor takes more than the message accepts the message
alone too, and then leaves its other attributes ``None``.
"""

from __future__ import annotations

from pathlib import Path


class DatasetNotFoundError(FileNotFoundError):
    """A dataset root, mission, modality or viewpoint folder is missing.

    The message names the path that was searched and what exists there instead.

    Args:
        what: what was looked for (``"ClaraVid root"``); alone, the whole message.
        searched: the path searched.
        hint: what to do, appended to the message.
    """

    def __init__(self, what: str, searched: str | Path | None = None, hint: str = "") -> None:
        if searched is None:  # the message alone (a rebuilt error)
            super().__init__(what)
            self.searched: Path | None = None
            return
        searched = Path(searched)
        parent = searched if searched.is_dir() else searched.parent
        # Hidden entries (.claravid-synth, .DS_Store) are not what the user is looking for.
        found = (
            sorted(p.name for p in parent.iterdir() if not p.name.startswith("."))[:20]
            if parent.is_dir()
            else []
        )
        where = f"; {parent} contains: {', '.join(found)}" if found else f"; {parent} is empty"
        if not parent.is_dir():
            where = f"; {parent} does not exist"
        message = f"{what} not found: searched {searched}{where}"
        if hint:
            message += f". {hint}"
        super().__init__(message)
        self.searched = searched


class CorruptFileError(ValueError):
    """A file exists but cannot be decoded (truncated, corrupt, or of the wrong kind).

    The message is ``cannot read PATH: REASON; ADVICE``, ``ADVICE`` being the class's
    (re-copy the file, for a damaged one).

    Args:
        path: the file; alone, the whole message (a rebuilt error: ``path`` and ``reason`` are
            then ``None`` and the message).
        reason: what is wrong with it.
    """

    advice = "re-copy or re-extract the file"

    def __init__(self, path: str | Path, reason: str | None = None) -> None:
        if reason is None:
            super().__init__(str(path))
            self.path: Path | None = None
            self.reason = str(path)
            return
        advice = f"; {self.advice}" if self.advice else ""
        super().__init__(f"cannot read {path}: {reason}{advice}")
        self.path = Path(path)
        self.reason = reason


class UnsupportedFileError(CorruptFileError):
    """A file that is intact but of a kind the readers refuse (a 12-bit or arithmetic-coded JPEG,
    an image larger than the readers accept); the reason says what to do instead of re-copying.
    """

    advice = ""

"""Errors that tell the user what was wrong and what to do about it."""

from __future__ import annotations

from pathlib import Path


class DatasetNotFoundError(FileNotFoundError):
    """A dataset root, mission, modality or viewpoint folder is missing.

    The message names the path that was searched and what exists there instead.
    """

    def __init__(self, what: str, searched: str | Path, hint: str = "") -> None:
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
    """A file exists but cannot be decoded (truncated, corrupt, or of the wrong kind)."""

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f"cannot read {path}: {reason}; re-copy or re-extract the file")
        self.path = Path(path)
        self.reason = reason

"""Where the toolkit keeps its caches: one answer for every cache (labels, class counts, DSP).

``$CLARAVID_CACHE`` when set to a non-empty path, else ``~/.cache/claravid``. An empty value
counts as unset: ``CLARAVID_CACHE= cmd`` is how shells unset a variable for one command, and
``Path("")`` would silently mean the current directory.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "CLARAVID_CACHE"


def cache_dir() -> Path:
    """``$CLARAVID_CACHE`` (``~`` expanded) when not empty, else ``~/.cache/claravid``."""
    value = os.environ.get(ENV_VAR, "")
    return Path(value).expanduser() if value.strip() else Path.home() / ".cache" / "claravid"

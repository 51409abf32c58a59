"""One cache directory for every cache: CLARAVID_CACHE when not empty, else ~/.cache/claravid."""

from pathlib import Path

import pytest

from claravid.data.label_cache import LabelCache
from claravid.dsp.cache import ComplexityCache
from claravid.infra.cachedir import cache_dir


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        (None, "HOME/.cache/claravid"),
        ("", "HOME/.cache/claravid"),  # was the current directory for the label cache
        ("  ", "HOME/.cache/claravid"),
        ("~/scratch", "HOME/scratch"),
        ("/fast/disk", "/fast/disk"),
    ],
)
def test_every_cache_agrees(monkeypatch, tmp_path, value, expected):
    monkeypatch.setenv("HOME", str(tmp_path))
    if value is None:
        monkeypatch.delenv("CLARAVID_CACHE", raising=False)
    else:
        monkeypatch.setenv("CLARAVID_CACHE", value)
    root = Path(expected.replace("HOME", str(tmp_path)))
    assert cache_dir() == root
    assert LabelCache().directory == root / "label_codes"
    assert ComplexityCache().path == root / "dsp.sqlite3"

"""Shared test set-up: no display, no network, no user caches."""

import os

import matplotlib
import pytest

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")
matplotlib.use("agg")


@pytest.fixture(autouse=True)
def _isolated_caches(tmp_path_factory, monkeypatch):
    """Point every cache (torch hub, ours) at a temp dir so no test reads or writes the user's."""
    cache = tmp_path_factory.getbasetemp() / "cache"
    monkeypatch.setenv("TORCH_HOME", str(cache / "torch"))
    monkeypatch.setenv("CLARAVID_CACHE", str(cache / "claravid"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache / "xdg"))

"""Shared test set-up: no display, no network, no user caches; the tiny generated ClaraVid tree."""

import os
import shutil

import matplotlib
import pytest

from claravid.synth import synthesize
from tests.helpers.files import use_hub_cache

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")
matplotlib.use("agg")


def pytest_configure(config):
    """Under ``pytest -n N`` (make test), the cores shared out: each worker's torch takes its share
    of the threads instead of all of them (N workers of 2 threads each on 2 cores run slower than
    N workers of one)."""
    workers = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
    if workers:
        import torch

        # The cores this process may run on (a container's, not the host's os.cpu_count()).
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        torch.set_num_threads(max(1, (cores or 1) // int(workers)))


# The session fixtures shared by tests/models, tests/train and tests/eval (tiny trained runs and
# their ONNX exports, each built once), and the short explanation of a failing comparison of
# large values (pytest's own takes minutes under CI).
pytest_plugins = ["tests.helpers.sessions", "tests.helpers.fail_fast"]

#: The missions of the tiny tree.
MISSIONS = ["rural_1", "urban_1"]


@pytest.fixture(scope="session", autouse=True)
def _dataloader_workers_joined_quickly():
    """Wait 0.25 s, not torch's 5 s, for each DataLoader worker at shutdown.

    A worker's error re-raised by torch leaves its iterator in a reference cycle (the raising
    frame holds the exception, whose traceback holds the frame), and so do some abandoned
    iterators: the garbage collector then shuts the workers down after their queues are
    finalised, so no worker hears the stop and each join waits out torch's whole status interval
    (5 s) in whichever later test the collection happens to run: 5 to 10 s several times a run.
    The join timeout is all this changes: a worker that does not exit in time is terminated, as
    torch does after 5 s.
    """
    from torch.utils.data import _utils

    before = _utils.MP_STATUS_CHECK_INTERVAL
    _utils.MP_STATUS_CHECK_INTERVAL = 0.25
    yield
    _utils.MP_STATUS_CHECK_INTERVAL = before


@pytest.fixture(autouse=True)
def _isolated_caches(tmp_path_factory, monkeypatch):
    """Point every cache (torch hub, ours) at a temp dir so no test reads or writes the user's."""
    cache = tmp_path_factory.getbasetemp() / "cache"
    monkeypatch.setenv("TORCH_HOME", str(cache / "torch"))
    monkeypatch.setenv("CLARAVID_CACHE", str(cache / "claravid"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache / "xdg"))
    # Hub ids read a prepared cache only: never the network, never the user's cache.
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    use_hub_cache(monkeypatch, cache / "huggingface")


@pytest.fixture(scope="session")
def claravid_root(tmp_path_factory):
    """Read-only tiny dataset: 2 missions × 6 viewpoints × 3 frames of 64×48, made once."""
    root = tmp_path_factory.mktemp("claravid") / "root"
    synthesize(root, seed=1, frames_per_viewpoint=3, size=(64, 48), missions=MISSIONS)
    return root


@pytest.fixture
def writable_root(claravid_root, tmp_path):
    """A private copy of the tiny dataset, for tests that damage files."""
    return shutil.copytree(claravid_root, tmp_path / "root")

"""A tiny ClaraVid-format tree, generated once per test session."""

import shutil

import pytest

from claravid.synth import synthesize

MISSIONS = ["rural_1", "urban_1"]


@pytest.fixture(scope="session")
def claravid_root(tmp_path_factory):
    """Read-only tiny dataset: 2 missions × 6 viewpoints × 3 frames of 64×48."""
    root = tmp_path_factory.mktemp("claravid") / "root"
    synthesize(root, seed=1, frames_per_viewpoint=3, size=(64, 48), missions=MISSIONS)
    return root


@pytest.fixture
def writable_root(claravid_root, tmp_path):
    """A private copy of the tiny dataset, for tests that damage files."""
    return shutil.copytree(claravid_root, tmp_path / "root")

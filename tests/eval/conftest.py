"""Evaluation tests run on the tiny generated ClaraVid tree of the data tests."""

from tests.claravid.conftest import claravid_root  # noqa: F401

"""A failing comparison of large values fails in seconds under CI, as it does elsewhere.

With ``CI`` set (``.ci/run`` sets it, as CI services do) pytest renders the whole difference of a
failing ``assert left == right``: for two checkpoints' bytes or two long float lists, difflib
takes minutes to hours (two float lists of 2,000 items: 90 s here), and the run times out instead
of failing. tests/helpers/fail_fast.py answers instead, with sizes, the first difference and
digests.
"""

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FAILING = """
import array
import random


def test_two_checkpoints_bytes_differ():
    r = random.Random(0)
    a = array.array("f", [r.gauss(0, 1) for _ in range(4096)]).tobytes()
    b = array.array("f", [r.gauss(0, 1) for _ in range(4096)]).tobytes()
    assert a == b


def test_two_long_float_lists_differ():
    r = random.Random(1)
    assert [r.random() for _ in range(2000)] == [r.random() for _ in range(2000)]
"""


def test_large_comparisons_fail_within_seconds_under_ci(tmp_path):
    test = tmp_path / "test_large.py"
    test.write_text(FAILING)
    from tests import conftest

    assert "tests.helpers.fail_fast" in conftest.pytest_plugins  # every run of tests/ loads it
    argv = [sys.executable, "-m", "pytest", "-p", "tests.helpers.fail_fast",
            "-p", "no:cacheprovider", "-q", "--rootdir", str(tmp_path), str(test)]  # fmt: skip
    env = {**os.environ, "CI": "1", "PYTHONPATH": str(ROOT)}
    start = time.monotonic()
    try:
        run = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, env=env, timeout=60)
    except subprocess.TimeoutExpired as stuck:
        raise AssertionError("a failing comparison of large values ran past 60 s") from stuck
    elapsed = time.monotonic() - start
    out = run.stdout
    assert run.returncode == 1 and "2 failed" in out, out[-3000:]
    assert elapsed < 30, elapsed  # a second or two of it is the failing itself
    assert "bytes of length 16,384 (sha256 " in out
    assert "list of length 2,000 == list of length 2,000: not equal" in out
    assert "2,000 of the first 2,000 positions differ" in out
    assert "compare large values by digest or with numpy.testing" in out

"""Fixes that must hold on every path that reaches them (issue 24 §1 items 2 and 3): ``--merge``
and ``--compare`` never load torch, and a bootstrap that cannot fit in memory is refused before
anything is allocated, in every mode of ``claravid-eval`` and every function of the API."""

import json
import subprocess
import sys

import pytest

# The console script as pip installs it: the entry point is loaded by its declared name, in a
# fresh interpreter, and what it imported is looked at once main() has returned.
_ENTRY_POINT = """
import sys
from importlib.metadata import entry_points

(script,) = [e for e in entry_points(group="console_scripts") if e.name == "claravid-eval"]
code = script.load()(sys.argv[1:])
print(json.dumps({"code": code, "torch": "torch" in sys.modules}))
"""


def _console_script(*argv):
    out = subprocess.run(
        [sys.executable, "-c", "import json\n" + _ENTRY_POINT, *map(str, argv)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("mode", ["merge", "compare"])
def test_merge_and_compare_never_load_torch(label_map_reports, tmp_path, mode):
    tmp = label_map_reports["tmp"]
    if mode == "merge":
        argv = ["--merge", tmp / "a", "--bins", "2", "-o", tmp_path / "m"]
    else:
        argv = ["--compare", tmp / "a", tmp / "b", "-o", tmp_path / "c"]
    done = _console_script(*argv, "--bootstrap", "100", "--no-progress")
    assert done == {"code": 0, "torch": False}
    assert (tmp_path / ("m" if mode == "merge" else "c")).is_dir()  # the work was done

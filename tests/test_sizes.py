"""Sizes the house keeps: functions under about 80 lines and modules under 600, read with ast.

The functions still longer are listed with their length today: one may shrink, none may grow,
and no new one may join them (the list is a ratchet, not a licence).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("claravid", "eval", "models", "train")
MOST_LINES = 80  # of a function, its docstring included
MODULE_LINES = 600
#: The functions over `MOST_LINES` today, and their lengths.
LONGER = {
    "claravid/data/index.py:list_frames": 109,
    "claravid/synth/scenery.py:props": 108,
    "claravid/data/blocks.py:deal_blocks": 108,
    "eval/measures/cross_view.py:cross_view": 97,
    "models/export/onnx.py:export_onnx": 90,
    "claravid/dsp/collection.py:compute_measures": 97,
    "eval/inputs/metric_csv.py:read_metrics_csv": 94,
}


def _functions() -> dict[str, int]:
    """``path:name`` -> lines of every function and method (the longest of a repeated name)."""
    lengths: dict[str, int] = {}
    for folder in FOLDERS:
        for file in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(file.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    key = f"{file.relative_to(ROOT).as_posix()}:{node.name}"
                    length = node.end_lineno - node.lineno + 1
                    lengths[key] = max(lengths.get(key, 0), length)
    return lengths


def test_no_function_grows_past_80_lines():
    lengths = _functions()
    assert len(lengths) > 1000  # the walk found the code
    too_long = {k: n for k, n in lengths.items() if n > LONGER.get(k, MOST_LINES)}
    assert too_long == {}, f"split these into named steps (at most {MOST_LINES} lines)"


def test_no_module_passes_600_lines():
    sizes = {
        file.relative_to(ROOT).as_posix(): len(file.read_text(encoding="utf-8").splitlines())
        for folder in FOLDERS
        for file in (ROOT / folder).rglob("*.py")
    }
    assert {f: n for f, n in sizes.items() if n > MODULE_LINES} == {}

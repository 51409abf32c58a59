"""The evaluation package's layers: imports point one way (that analysis and report never load
torch is one of the claims of tests/claravid/test_imports.py's probe)."""

import ast
from pathlib import Path

import pytest

EVAL = Path(__file__).resolve().parents[3] / "eval"
LAYERS = ("inputs", "measures", "inference", "analysis", "report")
# Which room may import which (the console scripts in cli/ may import all of them). analysis/ is
# numpy only and imports no other room; inputs/ scores saved label maps with measures/' sums.
ALLOWED = {"inputs": {"inputs", "measures", "analysis"}, "measures": {"measures", "analysis"},
           "inference": {"inference", "inputs", "measures", "analysis"}, "analysis": {"analysis"},
           "report": {"report", "analysis"}}  # fmt: skip


def _eval_imports(path: Path) -> set[str]:
    """The layers of claravid.eval a file imports (at any depth: lazy imports count too)."""
    layers = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[:2] == ["claravid", "eval"] and len(parts) > 2:
                layers.add(parts[2])
    return layers


@pytest.mark.parametrize("layer", LAYERS)
def test_imports_point_one_way(layer):
    for file in (EVAL / layer).rglob("*.py"):  # its subpackages too (analysis/bootstrap/)
        imported = _eval_imports(file)
        assert imported <= ALLOWED[layer], f"{file.name} of {layer} imports {imported}"


def test_data_and_models_never_import_eval_or_train():
    root = EVAL.parent
    for folder in ("claravid", "models"):
        for file in (root / folder).rglob("*.py"):
            source = file.read_text(encoding="utf-8")
            tree = ast.parse(source)
            for node in ast.walk(tree):
                module = node.module if isinstance(node, ast.ImportFrom) else None
                names = [module] if module else []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                for name in names:
                    assert not name.startswith(("claravid.eval", "claravid.train")), (
                        f"{file.relative_to(root)} imports {name}"
                    )

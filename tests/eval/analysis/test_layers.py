"""The evaluation package's layers: analysis and report never load torch; imports point one way."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

EVAL = Path(__file__).resolve().parents[3] / "eval"
LAYERS = ("inference", "analysis", "report")
# Which layer may import which (the console scripts beside them may import all three).
ALLOWED = {"inference": {"inference", "analysis"}, "analysis": {"analysis"},
           "report": {"report", "analysis"}}  # fmt: skip


def _modules(layer: str) -> list[str]:
    return sorted(
        f"claravid.eval.{layer}" + ("" if f.stem == "__init__" else f".{f.stem}")
        for f in (EVAL / layer).glob("*.py")
    )


@pytest.mark.parametrize("layer", ["analysis", "report"])
def test_numpy_layers_do_not_load_torch(layer):
    # A fresh interpreter: importing every module of the layer (and claravid.eval itself, whose
    # names are lazy) must leave torch unloaded, so --merge/--compare never pay for it.
    names = ["claravid.eval", *_modules(layer)]
    code = f"import sys\nfor m in {names!r}: __import__(m)\nprint('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", f"{layer} loads torch"


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
    for file in (EVAL / layer).glob("*.py"):
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

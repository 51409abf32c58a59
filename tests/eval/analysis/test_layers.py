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


#: What the numpy-only analysis layer may load of the toolkit (packages and these modules): the
#: profile fit and the measures' names of claravid.dsp, not its image code or the file readers;
#: the ClaraVid facts (the ignore id) of claravid.io, not its readers; the user-error class of
#: claravid.infra.cli (with the precision names its flags take); the packages' lazy names from
#: claravid.infra.lazy; the memory a bootstrap may take from claravid.infra.memory (the
#: kernel's MemAvailable, standard library only).
ANALYSIS_MAY_LOAD = ("claravid.eval.analysis", "claravid.dsp.measures", "claravid.dsp.profile",
                     "claravid.infra.cli", "claravid.infra.lazy", "claravid.infra.memory",
                     "claravid.infra.precision", "claravid.io.layout")  # fmt: skip
PACKAGES = {"claravid", "claravid.dsp", "claravid.eval", "claravid.infra", "claravid.io"}


def _loaded_after_importing(names: list[str]) -> set[str]:
    """The modules a fresh interpreter holds after importing ``names``."""
    code = f"import sys\nfor m in {names!r}: __import__(m)\nprint('\\n'.join(sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_analysis_loads_no_torch_no_opencv_no_files():
    """The analysis layer is numpy (and scipy) only: no torch, no OpenCV, no plots, and none of
    the toolkit's file readers or writers (claravid.io, the data layer, claravid.dsp's image code,
    claravid.infra.files, the report layer)."""
    loaded = _loaded_after_importing(["claravid.eval", *_modules("analysis")])
    heavy = sorted({"torch", "cv2", "matplotlib", "PIL", "tifffile"} & loaded)
    assert not heavy, heavy
    ours = {m for m in loaded if m.startswith("claravid")} - PACKAGES
    assert sorted(m for m in ours if not m.startswith(ANALYSIS_MAY_LOAD)) == []
    assert "claravid.dsp.profile" in ours  # the check sees what is loaded


def test_the_report_layer_does_not_load_torch():
    # Importing every module of the layer (and claravid.eval itself, whose names are lazy) must
    # leave torch unloaded, so --merge/--compare never pay for it.
    assert "torch" not in _loaded_after_importing(["claravid.eval", *_modules("report")])


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

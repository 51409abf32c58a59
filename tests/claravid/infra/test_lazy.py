"""Lazy public names (PEP 562): loaded on first use, and the same names for type checkers."""

import ast
import importlib
import importlib.util
import sys
import textwrap
from pathlib import Path

import pytest

from claravid.infra.lazy import lazy_exports

#: Every package whose public names are loaded on first use.
LAZY_PACKAGES = ["claravid", "claravid.dsp", "claravid.eval", "claravid.models"]


@pytest.fixture
def lazypkg(tmp_path, monkeypatch):
    """A throwaway package ``lazypkg`` with one lazily exported module, ``lazypkg.heavy``."""
    root = tmp_path / "lazypkg"
    root.mkdir()
    (root / "__init__.py").write_text(
        textwrap.dedent(
            """
            from claravid.infra.lazy import lazy_exports

            own = 1
            __getattr__, __dir__ = lazy_exports(__name__, {"Heavy": "lazypkg.heavy"})
            """
        )
    )
    (root / "heavy.py").write_text("class Heavy:\n    pass\n\nclass Hidden:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    for name in [m for m in sys.modules if m.split(".")[0] == "lazypkg"]:
        del sys.modules[name]


def test_a_name_loads_its_module_on_first_use_only(lazypkg):
    import lazypkg

    assert "lazypkg.heavy" not in sys.modules
    assert lazypkg.Heavy is sys.modules["lazypkg.heavy"].Heavy
    from lazypkg import Heavy

    assert Heavy.__module__ == "lazypkg.heavy"


def test_dir_lists_own_globals_and_exported_names(lazypkg):
    import lazypkg

    listed = dir(lazypkg)
    assert {"Heavy", "own", "__name__"} <= set(listed)
    assert listed == sorted(listed)
    assert "lazypkg.heavy" not in sys.modules  # listing imports nothing


def test_other_names_are_missing_attributes(lazypkg):
    import lazypkg

    # A name the module defines but the package does not export stays unexported.
    with pytest.raises(AttributeError, match=r"module 'lazypkg' has no attribute 'Hidden'"):
        lazypkg.Hidden  # noqa: B018
    assert not hasattr(lazypkg, "heavy_typo")
    with pytest.raises(ImportError, match="cannot import name 'Hidden'"):
        from lazypkg import Hidden  # noqa: F401


def test_the_export_table_is_a_copy():
    table = {"path": "os"}
    getattr_, _ = lazy_exports("os", table)
    table["sep"] = "os"
    with pytest.raises(AttributeError):
        getattr_("sep")
    assert getattr_("path") is sys.modules["os"].path


def _declared(package: str) -> tuple[list[str], dict[str, str], dict[str, str]]:
    """A package's ``__all__``, its ``TYPE_CHECKING`` imports and its ``lazy_exports`` table,
    read from its source ({name: module} each)."""
    source = Path(importlib.util.find_spec(package).origin)
    tree = ast.parse(source.read_text(encoding="utf-8"))
    names: list[str] = []
    typed: dict[str, str] = {}
    table: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", None) == "__all__":
            names = ast.literal_eval(node.value)
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom), ast.unparse(imp)
                typed.update({alias.name: imp.module for alias in imp.names})
            for stmt in node.orelse:
                call = stmt.value
                assert isinstance(call, ast.Call) and call.func.id == "lazy_exports"
                table = ast.literal_eval(call.args[1])
    return names, typed, table


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_type_checkers_see_the_names_that_run(package):
    """``__all__``, the imports type checkers read and the table that runs name the same
    things from the same modules."""
    names, typed, table = _declared(package)
    assert table, f"{package} has no lazy_exports table"
    assert typed == table
    assert sorted(names) == sorted(table)  # and no name twice (ruff keeps the order)


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_every_exported_name_resolves_to_its_module_s_object(package):
    module = importlib.import_module(package)
    _, _, table = _declared(package)
    for name, home in table.items():
        assert getattr(module, name) is getattr(importlib.import_module(home), name), name
    assert set(module.__all__) <= set(dir(module))


#: Names that left the public API: twins of a public name, or test-only helpers (each is still
#: importable from its room).
GONE = {
    "claravid.eval": ["evaluate_model", "merge_results", "compare_reports", "IGNORE_INDEX"],
    "claravid.models": ["hf_to_official", "official_to_hf", "BACKBONE_NAMES", "HEAD_NAMES"],
}


@pytest.mark.parametrize("package", sorted(GONE))
def test_the_public_api_is_one_name_per_concept(package):
    names, _, _ = _declared(package)
    assert len(names) <= 25, f"{package} exports {len(names)} names"
    module = importlib.import_module(package)
    for name in GONE[package]:
        assert name not in names and not hasattr(module, name), name

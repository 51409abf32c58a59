"""Imports stay light: the data layer needs no torch until a Dataset is used, and the models
need no data layer (no OpenCV, no albumentations)."""

import re
import subprocess
import sys


def test_claravid_dsp_and_the_patch_grid_do_not_import_torch():
    code = (
        "import sys, claravid, claravid.dsp, claravid.models.grid\n"
        "import claravid.data.sdk, claravid.data.palettes, claravid.data.splits\n"
        "from claravid import ClaravidDataset\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
        "from claravid import ClaraVidSegmentation\n"
        "assert 'torch' in sys.modules\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_models_do_not_import_the_data_layer():
    code = (
        "import sys, claravid.models\n"
        "from claravid.models import build_model, export_onnx, OnnxSegmenter\n"
        "heavy = sorted(m for m in ('cv2', 'albumentations', 'claravid.data.segmentation',\n"
        "               'claravid.data.transforms', 'claravid.data.index') if m in sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_the_short_transforms_path_is_a_module_of_its_own():
    """``claravid.transforms`` (the README's import) is a real module: its own spec, reloadable,
    the same functions as ``claravid.data.transforms``; the flat layout's paths are gone."""
    code = (
        "import importlib\n"
        "import claravid.transforms as short, claravid.data.transforms as data\n"
        "assert short.__spec__.name == 'claravid.transforms', short.__spec__\n"
        "assert data.__spec__.name == 'claravid.data.transforms', data.__spec__\n"
        "assert short.train_transforms is data.train_transforms\n"
        "assert set(short.__all__) <= set(dir(data))\n"
        "assert importlib.reload(short) is short\n"
        "for old in ('claravid.segmentation', 'claravid.cache_cli', 'claravid.labels'):\n"
        "    try:\n"
        "        importlib.import_module(old)\n"
        "    except ModuleNotFoundError:\n"
        "        continue\n"
        "    raise AssertionError(f'{old} still imports')\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_the_version_is_the_installed_distribution_s():
    from importlib.metadata import version

    import claravid

    assert claravid.__version__ == version("claravid-toolkit")


def documented_names() -> set[str]:
    """Every ``claravid...`` name the README and docs/ show: in code spans and in the imports of
    their Python blocks."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    names: set[str] = set()
    for page in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        text = page.read_text()
        names.update(re.findall(r"`(claravid(?:\.\w+)+)(?:\(\))?`", text))
        for block in re.findall(r"```python\n(.*?)```", text, re.S):
            for module, items in re.findall(
                r"^from (claravid[\w.]*) import ([\w, ]+)$", block, re.M
            ):
                names.update(f"{module}.{item.strip()}" for item in items.split(","))
            names.update(re.findall(r"^import (claravid[\w.]*)$", block, re.M))
    return names


def resolves(name: str) -> bool:
    """Import the longest module prefix of ``name``, then look the rest up as attributes."""
    import importlib

    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_every_name_the_docs_show_imports():
    from claravid.models.onnx_metadata import metadata_props

    # The readable ONNX metadata keys are spelled like module paths; they are not imports.
    document = {"patch_size": 14, "num_classes": 2, "model_args": {}, "precision": "fp32"}
    document |= {"input_size": [2, 4], "palette": {"name": "p"}, "window": {"size": [2, 4]}}
    keys = set(metadata_props(document)) - {"claravid"}
    names = documented_names() - keys
    assert {"claravid.transforms.train_transforms", "claravid.dsp.image_complexity"} <= names
    assert len(names) >= 25
    assert [name for name in sorted(names) if not resolves(name)] == []

"""Imports stay light: the data layer needs no torch until a Dataset is used, and the models
need no data layer (no OpenCV, no albumentations)."""

import re
import subprocess
import sys


def test_claravid_and_dsp_do_not_import_torch():
    code = (
        "import sys, claravid, claravid.dsp\n"
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


def test_every_former_module_path_is_the_moved_module():
    """Code and pickles written against the flat layout keep working: the old path imports the
    module at its new place (one module object)."""
    code = (
        "import importlib, pickle\n"
        "from claravid._moved import MOVED\n"
        "for old, new in MOVED.items():\n"
        "    assert importlib.import_module(old) is importlib.import_module(new), old\n"
        "from claravid.segmentation import ClaraVidSegmentation\n"
        "from claravid.data.segmentation import ClaraVidSegmentation as moved\n"
        "assert ClaraVidSegmentation is moved\n"
        "from claravid import transforms, jpeg_region\n"
        "assert transforms.train_transforms is importlib.import_module('claravid.data.transforms')"
        ".train_transforms\n"
        "from claravid.splits import SplitConfig\n"
        "assert type(pickle.loads(pickle.dumps(SplitConfig()))) is SplitConfig\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_the_moved_table_names_every_module_once():
    from pathlib import Path

    import claravid
    from claravid._moved import MOVED

    package = Path(claravid.__file__).parent
    modules = {
        f"claravid.{p.parent.name}.{p.stem}"
        for layer in ("infra", "io", "data")
        for p in (package / layer).glob("*.py")
        # New since the layout moved, so without a former path.
        if p.stem
        not in {
            "__init__",
            "shards",
            "cache_entries",
            "cache_prepare",
            "headers",
            "imagefile",
            "memory",
        }
    }
    assert set(MOVED.values()) == modules | {"claravid.synth.demo"}
    assert not any((package / f"{old.rsplit('.', 1)[1]}.py").exists() for old in MOVED)


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

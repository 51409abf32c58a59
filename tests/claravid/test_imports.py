"""Imports stay light: the data layer needs no torch until a Dataset is used, the models need no
data layer (no OpenCV, no albumentations), and the evaluation's analysis and report layers need no
torch (so --merge and --compare never pay for it)."""

import json
import re
import subprocess
import sys
from pathlib import Path

# One fresh interpreter checks every lightness claim: each claim imports its modules in a child
# forked from an interpreter that has loaded nothing of ours, so no claim sees another's imports.
PROBE = """
import json, os, sys

def claim(name, code, absent, then, loads, ours_allowed):
    pid = os.fork()
    if pid == 0:
        try:
            exec(code, {})
            wrong = sorted(m for m in absent if m in sys.modules)
            if ours_allowed is not None:
                packages, prefixes = ours_allowed
                wrong += sorted(m for m in sys.modules if m.startswith("claravid")
                                and m not in packages and not m.startswith(tuple(prefixes)))
            exec(then, {})  # the check can tell: this import does load it
            wrong += [f"{loads} not loaded by {then}"] if loads and loads not in sys.modules else []
            print(json.dumps({name: wrong}), flush=True)
        except BaseException as error:
            print(json.dumps({name: repr(error)}), flush=True)
        os._exit(0)
    os.waitpid(pid, 0)

for args in json.loads(sys.argv[1]):
    claim(*args)
"""


def _layer(name: str) -> str:
    """``import claravid.eval`` (its names are lazy) and every module of one of its layers."""
    folder = Path(__file__).resolve().parents[2] / "eval" / name
    modules = [f"claravid.eval.{name}" + ("" if f.stem == "__init__" else f".{f.stem}")
               for f in sorted(folder.glob("*.py"))]  # fmt: skip
    return "\n".join(f"import {m}" for m in ["claravid.eval", *modules])


#: What the numpy-only analysis layer may load of the toolkit (these packages, and modules with
#: these prefixes): the profile fit and the measures' names of claravid.dsp, not its image code or
#: the file readers; the ClaraVid facts (the ignore id) of claravid.io, not its readers; the
#: user-error class of claravid.infra.cli (with the precision names its flags take); the packages'
#: lazy names from claravid.infra.lazy; the memory a bootstrap may take from claravid.infra.memory
#: (the kernel's MemAvailable, standard library only).
ANALYSIS_MAY_LOAD = (
    ["claravid", "claravid.dsp", "claravid.eval", "claravid.infra", "claravid.io"],
    ["claravid.eval.analysis", "claravid.dsp.measures", "claravid.dsp.profile",
     "claravid.infra.cli", "claravid.infra.lazy", "claravid.infra.memory",
     "claravid.infra.precision", "claravid.io.layout"],
)  # fmt: skip

#: (claim, code, modules it must leave unloaded, code after the check, a module that code loads,
#: the toolkit modules it may load or None).
CLAIMS = [
    ("the data layer, dsp and the patch grid need no torch until a Dataset is used",
     "import claravid, claravid.dsp, claravid.models.grid\n"
     "import claravid.data.sdk, claravid.data.palettes, claravid.data.splits\n"
     "from claravid import ClaravidDataset",
     ["torch"], "from claravid import ClaraVidSegmentation", "torch", None),
    ("the models need no data layer (no OpenCV, no albumentations)",
     "import claravid.models\nfrom claravid.models import build_model, export_onnx, OnnxSegmenter",
     ["cv2", "albumentations", "claravid.data.segmentation", "claravid.data.transforms",
      "claravid.data.index"], "import cv2", "cv2", None),
    ("the command-line conventions and file writes pull in nothing heavy",
     "import claravid.infra.cli, claravid.infra.files", ["cv2", "albumentations", "torch"],
     "", "", None),
    # numpy (and scipy) only: no torch, no OpenCV, no plots, none of the toolkit's file readers or
    # writers (claravid.io, the data layer, claravid.dsp's image code, claravid.infra.files, the
    # report layer).
    ("claravid.eval.analysis is numpy only", _layer("analysis"),
     ["torch", "cv2", "matplotlib", "PIL", "tifffile"], "", "claravid.dsp.profile",
     ANALYSIS_MAY_LOAD),
    ("claravid.eval.report needs no torch", _layer("report"), ["torch"], "", "", None),
]  # fmt: skip


def test_every_lightness_claim_holds_in_a_fresh_interpreter():
    run = subprocess.run([sys.executable, "-c", PROBE, json.dumps(CLAIMS)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    found = {}
    for line in run.stdout.splitlines():
        found.update(json.loads(line))
    assert found == {claim[0]: [] for claim in CLAIMS}, found


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
    from claravid.models.export.metadata import metadata_props

    # The readable ONNX metadata keys are spelled like module paths; they are not imports.
    document = {"patch_size": 14, "num_classes": 2, "model_args": {}, "dtype": "fp32"}
    document |= {"input_size": [2, 4], "palette": {"name": "p"}, "window": {"size": [2, 4]}}
    keys = set(metadata_props(document)) - {"claravid"}
    names = documented_names() - keys
    assert {"claravid.transforms.train_transforms", "claravid.dsp.image_complexity"} <= names
    assert len(names) >= 25
    assert [name for name in sorted(names) if not resolves(name)] == []

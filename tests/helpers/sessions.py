"""Session fixtures: the tiny trained runs and ONNX exports that tests/models, tests/train and
tests/eval share (registered by tests/conftest.py).

Each is built once, on first use, in a session temp folder. Tests read them and never change
them: a test that damages a file copies it first. An export costs seconds (torch.export traces
the whole graph) and a run about one, so building each once is most of what keeps the suite
fast.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
from collections.abc import Mapping

import pytest
import torch

from tests.tiny import HEAD, VIT_56, tiny, tiny_v3


def _shared_folder(tmp_path_factory, name: str):
    """A folder every worker of this run reads (``pytest -n``: each worker's temp folder is its
    own, their parent the run's), for files that cost seconds to make and are the same in every
    worker. Its name holds what the files are made from, so workers that differ never share."""
    base = tmp_path_factory.getbasetemp()
    # Shared only where `_made_once` can lock (POSIX); elsewhere each worker makes its own.
    shared = os.environ.get("PYTEST_XDIST_WORKER") and os.name == "posix"
    root = base.parent if shared else base
    folder = root / "shared" / name
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@contextlib.contextmanager
def _made_once(folder):
    """Hold ``folder``'s lock: the first worker makes the files, the others wait, then reuse."""
    if os.name != "posix":  # a folder of this worker's own (`_shared_folder`)
        yield
        return
    import fcntl

    with open(folder / ".lock", "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _trained(cfg):
    """``train(cfg)`` on one thread, with the first tensor a module received (the normalised
    crops of the first step: the outermost call of a step is the model's forward)."""
    from claravid.train import train

    seen = []

    def first_input(module, args):
        if not seen and args and isinstance(args[0], torch.Tensor):
            seen.append(args[0].detach().clone())

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    handle = torch.nn.modules.module.register_module_forward_pre_hook(first_input)
    try:
        result = train(cfg)
    finally:
        handle.remove()
        torch.set_num_threads(before)
    return result, seen[0]


@pytest.fixture(scope="session")
def trained_v2(claravid_root, tmp_path_factory):
    """A tiny DINOv2 run (dinov2_vits14, 28² crops and windows) trained 3 steps on the tiny
    tree, validated once at the end: ``{"out", "ckpt" (last.pt), "cfg", "result",
    "first_input"}``."""
    from claravid.train import load_config

    out = tmp_path_factory.mktemp("v2_run") / "run"
    cfg = load_config("demo", tiny(claravid_root, out, "train.steps=3", "val.every=0"))
    result, first = _trained(cfg)
    return {"out": out, "ckpt": out / "last.pt", "cfg": cfg, "result": result,
            "first_input": first}  # fmt: skip


@pytest.fixture(scope="session")
def trained_sat(claravid_root, tmp_path_factory):
    """A tiny dinov3_vitl16_sat run (32² crops and windows) trained 2 steps from a config that
    names no statistics, validated once at the end: ``{"out", "ckpt" (last.pt), "cfg",
    "result", "first_input", "root"}``."""
    from claravid.train import load_config

    out = tmp_path_factory.mktemp("sat_run") / "run"
    overrides = tiny_v3(claravid_root, out, "train.steps=2", "val.every=0",
                        backbone="dinov3_vitl16_sat")  # fmt: skip
    cfg = load_config("demo", overrides)
    result, first = _trained(cfg)
    return {"out": out, "ckpt": out / "last.pt", "cfg": cfg, "result": result,
            "first_input": first, "root": str(claravid_root)}  # fmt: skip


#: claravid-export's flags of each of `trained_sat`'s exports.
SAT_EXPORT_FLAGS = {
    "fixed": ["--size", "32"],
    "dynamic": ["--dynamic", "--size", "32"],  # the example size; any patch multiple runs
    "fp16": ["--size", "32", "--dtype", "fp16"],
    "int8": ["--size", "32", "--dtype", "int8"],
}


class _Exports(Mapping):
    """`trained_sat`'s exports by name, each made on first use (an export costs seconds, and
    a worker of ``pytest -n`` runs only some of the tests that read them)."""

    def __init__(self, checkpoint, folder):
        self._checkpoint, self._folder = checkpoint, folder
        self._files: dict[str, object] = {}
        #: What each export made so far printed (the check's numbers).
        self.printed: dict[str, str] = {}

    def __getitem__(self, name):
        if name not in self._files:
            from claravid.eval.cli.export import main as export_main

            path = self._folder / f"{name}.onnx"
            text = io.StringIO()
            with contextlib.redirect_stdout(text):
                code = export_main(["--checkpoint", str(self._checkpoint), "-o", str(path),
                                    *SAT_EXPORT_FLAGS[name]])  # fmt: skip
            assert code == 0, (name, text.getvalue())
            self.printed[name] = text.getvalue()
            self._files[name] = path
        return self._files[name]

    def __iter__(self):
        return iter(SAT_EXPORT_FLAGS)

    def __len__(self):
        return len(SAT_EXPORT_FLAGS)


@pytest.fixture(scope="session")
def sat_exports(trained_sat, tmp_path_factory):
    """`trained_sat`'s exports through claravid-export, each checked by ONNX Runtime (exit 0 only
    then) and made on first use: ``fixed`` (its recorded 32² window), ``dynamic`` (height and
    width), ``fp16`` and ``int8`` (32²); ``.printed[name]`` holds what an export printed."""
    return _Exports(trained_sat["ckpt"], tmp_path_factory.mktemp("sat_exports"))


@pytest.fixture(scope="session")
def model_files(claravid_root, tmp_path_factory):
    """One untrained tiny DINOv2 segmenter (8 classes, `VIT_56`: a 4x4 positional grid) as a
    training-style checkpoint (its config names the data and the uavid palette) and a plain
    one (no config); ``model`` is the model itself. Its ONNX export is `model_onnx`."""
    from claravid import models

    folder = tmp_path_factory.mktemp("models")
    torch.manual_seed(0)
    model = models.build_model("dinov2_vits14", 8, backbone_kwargs=VIT_56, **HEAD).eval()
    config = {
        "data": {"root": str(claravid_root), "palette": "uavid", "split": {"seed": 0}},
        "val": {"window": 28, "scale": 1.0, "batch_size": 8},
        "other": [1, 2],
    }
    return {
        "checkpoint": models.save_checkpoint(model, folder / "best.pt", config=config, epoch=1),
        "plain": models.save_checkpoint(model, folder / "plain.pt"),
        "model": model,
    }


@pytest.fixture(scope="session")
def model_onnx(model_files, tmp_path_factory):
    """`model_files`' model exported with dynamic height and width, made at the native 56x56
    grid (so every other size interpolates the positional table): ``{"onnx", "export"}`` (the
    file and what `export_onnx` returned). Apart from `model_files`, as most of its users
    read only the checkpoints and an export costs seconds."""
    from claravid import models
    from tests.helpers.files import sha256

    # Made once per run: the model is seeded, so every worker's is the same (its digest says so).
    folder = _shared_folder(tmp_path_factory, f"model_onnx-{sha256(model_files['plain'])[:16]}")
    path, record = folder / "model.onnx", folder / "export.json"
    with _made_once(folder):
        if not record.exists():
            settings = models.ExportSettings(height=56, width=56, dynamic=True)
            result = models.export_onnx(model_files["model"], path, settings)
            record.write_text(json.dumps(result, default=str))
    return {"onnx": path, "export": json.loads(record.read_text())}


@pytest.fixture
def trained_v2_copy(trained_v2, tmp_path):
    """A private copy of `trained_v2`'s folder, for tests that damage it."""
    return shutil.copytree(trained_v2["out"], tmp_path / "run")

"""The built wheel, installed outside the checkout, carries everything it reads at run time.

It installs one top-level package, ``claravid`` (``claravid.models``, ``claravid.train``,
``claravid.eval``): a user's own ``models``/``train``/``eval`` packages neither shadow ours nor
are shadowed by them.
"""

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from claravid.models.checkpoint import read_checkpoint
from claravid.train.config import from_plain
from tests.helpers.scoring import miou_by_hand

ROOT = Path(__file__).resolve().parents[1]

# Run from an empty folder with only the installed wheel ahead of site-packages on the path:
# the checkout is not importable, so every shipped file must come from the wheel.
PROBE = """
import sys
from pathlib import Path
target = Path(sys.argv[1]).resolve()
import claravid, claravid.models, claravid.train, claravid.eval
for module in (claravid, claravid.models, claravid.train, claravid.eval):
    assert Path(module.__file__).resolve().is_relative_to(target), module.__file__
from claravid.data.palettes import available_palettes, load_palette
from claravid.infra.resources import shipped_names
names = available_palettes()
assert {"claravid", "uavid"} <= set(names), names
assert load_palette("uavid").num_classes == 8
from claravid.synth import synthesize
from claravid.data.segmentation import ClaraVidSegmentation
synthesize(Path(sys.argv[2]) / "data", seed=0, frames_per_viewpoint=1, size=(84, 70),
           missions=["urban_1"], progress=False)
sample = ClaraVidSegmentation(Path(sys.argv[2]) / "data", split="all", palette="uavid")[0]
assert tuple(sample["mask"].shape) == (70, 84), sample["mask"].shape
from claravid.train.config import load_config
cfg = load_config("demo", ["train.steps=3"])  # a named experiment config, from the wheel
assert cfg.model.freeze_backbone is False and cfg.train.steps == 3, cfg
assert load_config("claravid_dpt_vitl14").model.backbone == "dinov2_vitl14"
sat = load_config("claravid_dpt_dinov3_vitl16_sat", ["model.weights=/w.pth"])  # DINOv3, shipped
assert tuple(sat.data.augment.mean) == (0.430, 0.411, 0.296) and sat.val.window == 640, sat
assert load_config("claravid_dpt_dinov3_vitl16", ["model.weights=/w.pth"]).val.window == 640
for head in ("linear", "upernet"):  # the heads' configs, shipped
    cfg = load_config(f"claravid_{head}_dinov3_vitl16_sat", ["model.weights=/w.pth"])
    assert cfg.model.head == head, cfg
print("OK", ",".join(names), ",".join(shipped_names()))
"""


@pytest.mark.slow
def test_wheel_installed_outside_checkout_loads_palettes_and_a_sample(tmp_path):
    # Build from a clean copy: an in-tree build reuses build/lib, where a module deleted from
    # the checkout would survive and be packaged.
    source = shutil.copytree(
        ROOT, tmp_path / "source",
        ignore=shutil.ignore_patterns(".git", ".venv", "runs", "build", "*.egg-info", "*.so",
                                      "__pycache__", ".pytest_cache", ".ruff_cache",
                                      ".mypy_cache"),
    )  # fmt: skip
    wheels = tmp_path / "wheels"
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(wheels), str(source)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = wheels.glob("claravid_toolkit-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top_level = {name.split("/")[0] for name in names if not name.startswith("claravid_toolkit-")}
    assert top_level == {"claravid"}, sorted(top_level)
    assert "claravid/models/backbones/dinov2.py" in names and "claravid/train/loop.py" in names
    assert "claravid/eval/cli/evaluate.py" in names
    assert "claravid/configs/palettes/uavid.yaml" in names
    assert {"claravid/py.typed", "claravid/dsp/_deldensity.pyi"} <= set(names)  # typed
    assert "claravid/configs/augment.yaml" in names
    assert "claravid/configs/demo.yaml" in names
    assert "claravid/configs/claravid_dpt_dinov3_vitl16.yaml" in names
    assert "claravid/configs/claravid_dpt_dinov3_vitl16_sat.yaml" in names
    for head in ("linear", "upernet"):
        for weights in ("", "_sat"):
            assert f"claravid/configs/claravid_{head}_dinov3_vitl16{weights}.yaml" in names

    target = tmp_path / "site"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target),
         str(wheel)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert install.returncode == 0, install.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()
    run = subprocess.run(
        [sys.executable, "-c", PROBE, str(target), str(work)],
        capture_output=True, text=True, cwd=work, timeout=600,
        env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path),
             "NO_ALBUMENTATIONS_UPDATE": "1", "CLARAVID_CACHE": str(tmp_path / "cache")},
    )  # fmt: skip
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    ok, palettes, _ = run.stdout.split(" ", 2)
    assert ok == "OK" and {"claravid", "uavid", "udd6"} <= set(palettes.split(","))

    # A user's project with its own models/, train/ and eval/ packages, ahead of ours on the
    # path: the console scripts must never import them.
    user = tmp_path / "user_project"
    for package in ("models", "train", "eval"):
        (user / package).mkdir(parents=True)
        (user / package / "__init__.py").write_text(
            f"raise ImportError('the user\\'s own {package} package was imported')\n"
        )
    env = {"PYTHONPATH": f"{user}{os.pathsep}{target}", "PATH": "/usr/bin:/bin",
           "HOME": str(tmp_path), "NO_ALBUMENTATIONS_UPDATE": "1",
           "CLARAVID_CACHE": str(tmp_path / "cache")}  # fmt: skip
    data = work / "data"
    train = subprocess.run(
        [str(target / "bin" / "claravid-train"), "--config", "demo", f"data.root={data}",
         "train.steps=2", "train.batch_size=2", "data.num_workers=0", "val.every=0",
         # 6 frames of one mission make one 150 m block, all of it train: validate on all.
         "val.bins=1", "data.val_split=all",
         f"out_dir={user / 'run'}"],
        capture_output=True, text=True, cwd=user, env=env, timeout=600,
    )  # fmt: skip
    assert train.returncode == 0, train.stdout[-2000:] + train.stderr[-3000:]
    last = read_checkpoint(user / "run" / "last.pt")
    # 2 steps of 2 frames, on the data the wheel's probe generated, with the user's overrides.
    assert last["step"] == 2 and last["sampler"] == {"step": 2, "frames_seen": 4}
    assert last["config"]["data"]["root"] == str(data)
    assert last["config"]["data"]["val_split"] == "all" and last["config"]["val"]["bins"] == 1
    evaluate = subprocess.run(
        [str(target / "bin" / "claravid-eval"), "--checkpoint", str(user / "run" / "last.pt"),
         "--split", "all", "--no-progress", "--output", str(user / "report")],
        capture_output=True, text=True, cwd=user, env=env, timeout=600,
    )  # fmt: skip
    assert evaluate.returncode == 0, evaluate.stdout[-2000:] + evaluate.stderr[-3000:]
    report = json.loads((user / "report" / "report.json").read_text())
    # Every frame the probe generated (urban_1: 3 altitudes × 2 directions × 1), each once.
    frames = sorted(str(p) for p in (data / "003_urban_1" / "left_rgb").glob("*/*.jpg"))
    assert len(frames) == 6 and sorted(r["path"] for r in report["images"]) == frames
    assert report["overall"]["num_images"] == 6
    # Its mIoU, counted with numpy from the checkpoint's predictions on those frames.
    cfg = from_plain(last["config"])
    assert report["overall"]["miou"] == pytest.approx(miou_by_hand(user / "run" / "last.pt", cfg))

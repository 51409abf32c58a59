"""model.init: a run starts from another run's head (and stored backbone), not a resume; a
checkpoint of another palette, backbone or head shape is refused in one line."""

import torch

from claravid import models
from claravid.data.palettes import load_palette
from claravid.models.checkpoint import read_checkpoint
from claravid.train import load_config
from claravid.train.cli import main
from claravid.train.loop import build_run
from claravid.train.outdir import MARKER
from tests.models.backbones.reference import random_official_state
from tests.tiny import MODEL, tiny


def _uavid(root, out, *extra):
    """A tiny run on the tiny UAVid tree, in the demo config's tiny model (UAVid's 8 classes)."""
    return tiny(root, out, "data.dataset=uavid", "data.val_dataset=uavid", "data.val_split=val",
                "train.steps=1", "val.every=0", *extra)  # fmt: skip


def _saved(path, num_classes=8, backbone="dinov2_vits14", **extra):
    """A model file of the tiny architecture (8-channel DPT head, random backbone stored)."""
    torch.manual_seed(5)
    model = models.build_model(backbone, num_classes, **{**MODEL, **extra.pop("model", {})})
    models.save_checkpoint(model, path, **extra)
    return path


def test_init_starts_from_the_source_weights_at_step_0(trained_v2, uavid_root, tmp_path):
    source = read_checkpoint(trained_v2["ckpt"])
    said = []
    init = f"model.init={trained_v2['ckpt']}"
    cfg = load_config("demo", _uavid(uavid_root, tmp_path / "run", init))
    run = build_run(cfg, resume=False, say=said.append)
    own = run.model.state_dict()
    # The demo trains its tiny backbone too, so the file stores it: head and backbone load.
    assert source["backbone_included"] and set(source["model"]) == set(own)
    for key, value in source["model"].items():
        assert torch.equal(own[key], value), key
    # Not a resume: step 0, a fresh optimiser, this config's schedule.
    assert run.start == 0 and run.total == 1 and not run.optimizer.state
    assert run.best_miou is None
    assert any(f"head and backbone from {trained_v2['ckpt']} (step 3" in s for s in said), said
    # A run built the same way without model.init starts elsewhere (the test would notice a
    # load that did nothing).
    plain = load_config("demo", _uavid(uavid_root, tmp_path / "plain"))
    fresh = build_run(plain, resume=False, say=lambda *_: None).model.state_dict()
    head = [k for k in own if k.startswith("head.") and own[k].is_floating_point()]
    assert head and all(not torch.equal(fresh[k], own[k]) for k in head if own[k].numel() > 1)


def test_a_run_from_init_records_its_source(trained_v2, uavid_root, tmp_path):
    out = tmp_path / "run"
    init = f"model.init={trained_v2['ckpt']}"
    assert main(["--config", "demo", *_uavid(uavid_root, out, init)]) == 0
    ckpt = read_checkpoint(out / "last.pt")
    assert ckpt["init"]["path"] == str(trained_v2["ckpt"]) and ckpt["init"]["step"] == 3
    assert ckpt["init"]["backbone_loaded"] and ckpt["backbone_included"]
    assert ckpt["config"]["model"]["init"] == str(trained_v2["ckpt"])
    assert ckpt["step"] == 1  # this run's own steps, from 0


def _refused(capsys, args, out, *words):
    assert main(["--config", "demo", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, err
    assert not out.exists()  # refused before the run folder was made: nothing half-written
    return err


def test_init_refuses_a_missing_file_or_a_foreign_one(uavid_root, tmp_path, capsys):
    out = tmp_path / "run"
    missing = tmp_path / "nowhere" / "best.pt"
    _refused(capsys, _uavid(uavid_root, out, f"model.init={missing}"), out,
             f"model.init={missing}", "no such file")  # fmt: skip
    text = tmp_path / "notes.pt"
    text.write_text("not a checkpoint")
    _refused(capsys, _uavid(uavid_root, out, f"model.init={text}"), out, f"model.init={text}")


def test_init_refuses_another_palette(uavid_root, tmp_path, capsys):
    out = tmp_path / "run"
    # 19 classes from ClaraVid's palette, into a run of UAVid's 8.
    fine = _saved(tmp_path / "claravid.pt", 19, config={"data": {"palette": "claravid"}})
    _refused(capsys, _uavid(uavid_root, out, f"model.init={fine}"), out,
             f"model.init={fine}", "19 classes", "data.palette")  # fmt: skip
    # 8 classes, but not UAVid's in its order: the count alone would not show it.
    names = list(reversed(load_palette("uavid").names))
    swapped = _saved(tmp_path / "swapped.pt", 8, classes=names)
    _refused(capsys, _uavid(uavid_root, out, f"model.init={swapped}"), out,
             f"model.init={swapped}", "another class set", "data.palette")  # fmt: skip


def test_init_refuses_another_backbone(uavid_root, tmp_path, capsys):
    out = tmp_path / "run"
    names = list(load_palette("uavid").names)
    base = _saved(tmp_path / "b.pt", backbone="dinov2_vitb14", classes=names)
    words = (f"model.init={base}", "another backbone", "dinov2_vitb14", "model.backbone")
    _refused(capsys, _uavid(uavid_root, out, f"model.init={base}"), out, *words)
    deeper = _saved(tmp_path / "d.pt", classes=names, model={"backbone_kwargs": {
        **MODEL["backbone_kwargs"], "depth": 5}})  # fmt: skip
    _refused(capsys, _uavid(uavid_root, out, f"model.init={deeper}"), out,
             f"model.init={deeper}", "another backbone", "'depth': 5")  # fmt: skip


def test_init_refuses_another_head_shape_and_the_folder_stays_free(uavid_root, tmp_path, capsys):
    out = tmp_path / "run"
    names = list(load_palette("uavid").names)
    wide = _saved(tmp_path / "w.pt", classes=names, model={"features": 16})
    # The head's defaults are filled in with the model: refused once it is built, before any
    # step, so the folder binds nothing and the next run may take it.
    assert main(["--config", "demo", *_uavid(uavid_root, out, f"model.init={wide}")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"model.init={wide}" in err and "model.features" in err
    assert not (out / "last.pt").exists() and not (out / "metrics.jsonl").exists()
    assert {p.name for p in out.iterdir()} == {MARKER}  # a budget of 1.0 writes no budget.json
    assert main(["--config", "demo", *_uavid(uavid_root, out)]) == 0


def test_a_frozen_backbone_from_a_weights_file_loads_the_head_only(
    claravid_root, uavid_root, tmp_path, capsys
):
    """The paper's path: the backbone is a weights file, frozen; the checkpoints reference it,
    so model.init loads the head, and the new run's checkpoints reference the file too."""
    weights = tmp_path / "dino.pth"
    backbone = models.build_model("dinov2_vits14", 8, **MODEL).backbone
    torch.save(random_official_state(backbone, seed=3), weights)
    frozen = [f"model.weights={weights}", "model.freeze_backbone=true"]
    source = tmp_path / "source"
    args = tiny(claravid_root, source, "train.steps=1", "val.every=0", *frozen)
    assert main(["--config", "demo", *args]) == 0
    stored = read_checkpoint(source / "last.pt")
    assert not stored["backbone_included"]
    out = tmp_path / "run"
    cfg = load_config("demo", _uavid(uavid_root, out, f"model.init={source / 'last.pt'}", *frozen))
    said = []
    run = build_run(cfg, resume=False, say=said.append)
    own = run.model.state_dict()
    for key, value in stored["model"].items():  # the head, and nothing else, is the source's
        assert torch.equal(own[key], value), key
    assert not run.store_backbone and any("model.init: head from" in s for s in said), said
    # Other backbone weights than the source's: its head would read other features.
    other = _uavid(uavid_root, tmp_path / "other", f"model.init={source / 'last.pt'}",
                   "model.weights=null")  # fmt: skip
    _refused(capsys, other, tmp_path / "other", "other backbone weights", "model.weights")


def test_a_resumed_run_continues_from_its_own_checkpoint_not_model_init(
    trained_v2, uavid_root, tmp_path, capsys
):
    source = tmp_path / "source.pt"
    source.write_bytes(trained_v2["ckpt"].read_bytes())
    out = tmp_path / "run"
    args = ["--config", "demo", *_uavid(uavid_root, out, f"model.init={source}")]
    assert main(args) == 0
    source.unlink()  # gone: a resume does not read it again
    assert main([*args, "--resume"]) == 0
    assert "already finished" in capsys.readouterr().out

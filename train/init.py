"""Starting a run from another run's checkpoint (``model.init``): pretraining, then fine-tuning.

``model.init=runs/claravid/best.pt`` loads that checkpoint's head, and its backbone when the
file stores one (a backbone it trained, or a random init), into the freshly built model before
the first step. It is not a resume: the optimiser, scheduler, step, best score and RNG start
afresh, and the data and schedule are this config's. The source must have been trained on the
same backbone (name, architecture, weights) with the same head and the same class names, in
the same order: a head trained for other classes or on other features would load without an
error and mean nothing. Each refusal is one line naming the file and the key to change;
:func:`read_init` makes the checks that need no model before anything is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from claravid.data.palettes import load_palette
from claravid.models.checkpoint import CheckpointError, read_checkpoint
from claravid.models.segmenter import Segmenter

#: The head settings a checkpoint's ``model_args`` records (those of its head only).
HEAD_SETTINGS = ("layers", "features", "out_channels", "use_cls")


class InitError(ValueError):
    """``model.init`` names a file this run cannot start from (the message says why)."""


def _classes(ckpt: dict[str, Any]) -> list[str] | None:
    """The class names the checkpoint's head predicts: its ``classes`` entry, else its training
    config's palette; None when neither says."""
    if isinstance(ckpt.get("classes"), list):
        return [str(c) for c in ckpt["classes"]]
    palette = ((ckpt.get("config") or {}).get("data") or {}).get("palette")
    if palette is None:
        return None
    try:
        return list(load_palette(palette).names)
    except (OSError, ValueError):  # a palette file that has gone: compare the class count
        return None


def _same_weights(source: Any, target: Any) -> bool:
    """Whether two ``model.weights`` values name the same backbone weights (a file may have
    moved: the same file name counts as the same file)."""
    if source is None or target is None:
        return source is None and target is None
    return source == target or Path(str(source)).name == Path(str(target)).name


def read_init(path: str | Path, backbone: str, backbone_kwargs: dict[str, Any], weights: Any,
              head: str, classes: list[str]) -> dict[str, Any]:  # fmt: skip
    """Read ``model.init`` and check it can start a run of this backbone, head and classes.

    Args:
        path: the checkpoint (``model.init``).
        backbone, backbone_kwargs, weights, head: this run's ``model.*`` values.
        classes: this run's class names (``data.palette``'s), in train-id order.

    Returns:
        The checkpoint, for :func:`apply_init`.

    Raises:
        InitError: no such file, not a model checkpoint, or another backbone, head or palette.
    """
    where = f"model.init={path}"
    if not Path(path).is_file():
        what = "a folder, not a file" if Path(path).is_dir() else "no such file"
        raise InitError(f"{where}: {what}; pass the best.pt or last.pt of the run to start from")
    try:
        ckpt = read_checkpoint(path)
    except (CheckpointError, OSError) as exc:
        raise InitError(f"{where}: {exc}") from None
    args = ckpt["model_args"]
    theirs = (args.get("backbone"), dict(args.get("backbone_kwargs") or {}))
    if theirs != (backbone, dict(backbone_kwargs)):
        raise InitError(
            f"{where} was trained on another backbone ({_backbone(*theirs)}; this run's "
            f"model.backbone is {_backbone(backbone, backbone_kwargs)}): start from a "
            "checkpoint of this backbone, or set model.backbone (and model.backbone_kwargs) to its"
        )
    if not _same_weights(args.get("weights"), weights):
        raise InitError(
            f"{where} was trained on other backbone weights (model.weights={args.get('weights')} "
            f"there, {weights} here): its head reads other features; set model.weights to its"
        )
    if args.get("head") != head:
        raise InitError(
            f"{where} holds a {args.get('head')} head and this run trains model.head={head}: "
            f"set model.head={args.get('head')}, or start from a checkpoint of a {head} head"
        )
    source = _classes(ckpt)
    count = int(args.get("num_classes", -1))
    if (source is not None and source != list(classes)) or count != len(classes):
        named = f" ({', '.join(source[:4])}{', ...' if len(source) > 4 else ''})" if source else ""
        raise InitError(
            f"{where} predicts another class set: {count} classes{named}, and data.palette "
            f"gives {len(classes)} ({', '.join(classes[:4])}{', ...' if len(classes) > 4 else ''})"
            "; train the source with this palette, or set data.palette to the source's"
        )
    return ckpt


def _backbone(name: Any, kwargs: dict[str, Any]) -> str:
    return f"{name} {kwargs}" if kwargs else str(name)


def apply_init(model: Segmenter, ckpt: dict[str, Any], path: str | Path) -> bool:
    """Load the checkpoint's head (and stored backbone) into ``model``; whether the backbone
    was loaded too (then the run's checkpoints must store it).

    Raises:
        InitError: the head's settings differ (``model.layers``, ``features`` ...).
    """
    args = ckpt["model_args"]
    differ = [k for k in HEAD_SETTINGS if args.get(k) != model.model_args.get(k)]
    if differ:
        key = differ[0]
        raise InitError(
            f"model.init={path} holds a head of another shape: model.{key} is {args.get(key)} "
            f"there and {model.model_args.get(key)} here; set model.{key}={args.get(key)}"
        )
    with_backbone = bool(ckpt.get("backbone_included", True))
    state = {
        k: v for k, v in ckpt["model"].items() if with_backbone or not k.startswith("backbone.")
    }
    own = model.state_dict()
    wanted = {k for k in own if with_backbone or not k.startswith("backbone.")}
    if wanted != set(state) or any(state[k].shape != own[k].shape for k in wanted):
        missing = sorted(wanted ^ set(state))[:3]
        raise InitError(f"model.init={path} does not match its own model_args (keys {missing})")
    with torch.no_grad():
        model.load_state_dict(state, strict=with_backbone)
    return with_backbone


def init_record(ckpt: dict[str, Any], path: str | Path) -> dict[str, Any]:
    """What a run records of the checkpoint it started from."""
    return {
        "path": str(path),
        "step": ckpt.get("step"),
        "best_miou": ckpt.get("best_miou"),
        "palette": ((ckpt.get("config") or {}).get("data") or {}).get("palette"),
        "backbone_loaded": bool(ckpt.get("backbone_included", True)),
    }

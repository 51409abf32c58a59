"""Backbone weights: one loader for every format people download.

``weights=`` may be a file (official ``.pth``, a Hugging Face or timm ``model.safetensors`` or
``pytorch_model.bin``), a folder holding one (a ``save_pretrained`` folder, a hub snapshot,
sharded checkpoints with their index), a Hugging Face hub id (`claravid.models.weights.hub`), or
``"official"`` (the DINOv2 download). The loader reads the tensors, detects the format among the
family's declared ones (`claravid.models.weights.dinov2`, `claravid.models.weights.dinov3`),
renames them to the official names, checks that they are this backbone's (family, size,
pre-training data, ``config.json``, values) and loads them strictly. Every refusal is one
`WeightsError` that says what the weights are and what to do.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from claravid.models.backbones.specs import BackboneSpec
from claravid.models.weights.formats import (
    State,
    WeightsError,
    absent_keys,
    detect_format,
    to_official,
)
from claravid.models.weights.hub import (  # noqa: F401  (official_url, official_checkpoint_path: API)
    download_official,
    hub_snapshot,
    incomplete_download,
    is_hub_id,
    official_checkpoint_path,
    official_url,
    repo_folder_snapshot,
)
from claravid.models.weights.identity import (
    WEIGHTS_FAMILIES,
    WeightsWarning,
    check_config,
    check_family,
    check_identity,
    fitting,
    state_shape,
)
from claravid.models.weights.torchfile import read_tensor_file

__all__ = [
    "WeightsError",
    "WeightsSource",
    "WeightsWarning",
    "load_weights",
    "locate_weights",
    "read_weights",
]

_SUFFIXES = (".safetensors", ".bin", ".pth", ".pt")
_SHARD = re.compile(r".+-(\d{5})-of-(\d{5})\.(safetensors|bin)")
# Where the Hugging Face convention stores the same weights twice: the first is read.
_PAIRS = (("model.safetensors", "pytorch_model.bin"),)


@dataclass(frozen=True)
class WeightsSource:
    """Weights found on disk.

    Attributes:
        given: What the caller passed (a path, a hub id or ``"official"``).
        files: The weights files (several: the shards of one checkpoint).
        config: The ``config.json`` beside them (Hugging Face or timm), or None.
        hub_id: The hub repository they came from, or None.
    """

    given: str
    files: tuple[Path, ...]
    config: Mapping[str, Any] | None = None
    hub_id: str | None = None

    @property
    def nbytes(self) -> int:
        """Bytes of the weights files (read whole before they are copied in)."""
        return sum(f.stat().st_size for f in self.files)

    @property
    def names(self) -> list[str]:
        """Names that may say whose weights these are: the hub id, the file names (also behind
        a symbolic link), the folder, a hub-cache repository folder."""
        names = [self.hub_id] if self.hub_id else []
        first = self.files[0]
        for file in self.files[:1]:
            names += [file.name, file.resolve().name]
        repo = next((p for p in first.parts if p.startswith("models--")), None)
        if repo is not None:
            names.append(repo.removeprefix("models--").replace("--", "/"))
        names.append(first.parent.name)
        return list(dict.fromkeys(n for n in names if n))

    def __str__(self) -> str:
        return self.given


def _missing_hint(spec: BackboneSpec) -> str:
    timm = next((h for h in spec.weights.hub if h.startswith("timm/")), "timm/...")
    official = "'official' to download the official file, " if spec.weights.url else ""
    return (
        f"; pass an existing .pth/.safetensors file or a folder holding one, a hub id such as "
        f"{timm!r}, {official}or None for a random init"
    )


def locate_weights(weights: str | os.PathLike, spec: BackboneSpec) -> WeightsSource:
    """Find the files of ``weights`` (a path, a folder, a hub id or ``"official"``).

    Raises:
        FileNotFoundError: no such file or folder, and not a hub id.
        WeightsError: a folder without weights or with several, one shard of a sharded
            checkpoint, a hub id that cannot be had (`claravid.models.weights.hub.hub_snapshot`),
            ``"official"`` for licence-gated weights.
    """
    given = str(weights)
    if given == "official":
        return WeightsSource(given, (download_official(spec.name),))
    if not given.strip():  # Path("") is the current folder
        hint = _missing_hint(spec).replace(";", ":", 1)
        raise WeightsError(f"weights={given!r} names nothing{hint}")
    path = Path(weights)
    if path.is_dir():
        snapshot = repo_folder_snapshot(path)
        if snapshot is not None:  # a models--org--name folder of the hub cache
            hub_id = path.name.removeprefix("models--").replace("--", "/")
            return _from_folder(snapshot, given, hub_id=hub_id)
        return _from_folder(path, given)
    if path.is_file():
        if path.name.endswith(".index.json"):
            return _from_folder(path.parent, given, index=path)
        if _SHARD.fullmatch(path.name):
            raise WeightsError(
                f"{path} is one shard of a sharded checkpoint: pass the folder that holds all "
                "of them and the .index.json"
            )
        return WeightsSource(given, (path,), _read_config(path.parent))
    if isinstance(weights, str) and is_hub_id(weights):
        return _from_folder(hub_snapshot(weights), given, hub_id=weights)
    raise FileNotFoundError(f"weights file {path} not found{_missing_hint(spec)}")


def _from_folder(
    folder: Path, given: str, hub_id: str | None = None, index: Path | None = None
) -> WeightsSource:
    """The weights of a folder: its sharded checkpoint, or its one weights file."""
    indexes = [index] if index else sorted(folder.glob("*.index.json"))
    if indexes:
        files = _shards(indexes[0])
    else:
        found = sorted(
            f
            for f in folder.iterdir()
            if f.is_file() and f.suffix in _SUFFIXES and f.name[0] != "."
        )
        names = {f.name for f in found}
        for first, second in _PAIRS:
            if first in names:
                found = [f for f in found if f.name != second]
        if not found:
            incomplete = incomplete_download(folder, hub_id)
            if incomplete is not None:
                raise incomplete
            raise WeightsError(
                f"folder {folder} holds no weights file (*.safetensors, *.bin, *.pth, *.pt): "
                "pass the folder a download or save_pretrained wrote, or the file itself"
            )
        if len(found) > 1:
            listed = ", ".join(f.name for f in found)
            raise WeightsError(
                f"folder {folder} holds {len(found)} weights files ({listed}): pass the one "
                "you mean"
            )
        files = tuple(found)
    return WeightsSource(given, files, _read_config(folder), hub_id)


def _shards(index: Path) -> tuple[Path, ...]:
    try:
        weight_map = json.loads(index.read_text())["weight_map"]
        names = sorted(set(weight_map.values()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise WeightsError(
            f"cannot read the shard index {index} ({exc}): download it again"
        ) from None
    if not names:
        raise WeightsError(
            f"the shard index {index} lists no shards (its weight_map is empty): download it "
            "again, or pass the weights file itself"
        )
    missing = [n for n in names if not (index.parent / n).is_file()]
    if missing:
        raise WeightsError(
            f"the sharded checkpoint {index} lists {len(names)} shards, and {', '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} missing in {index.parent}: download "
            "every shard"
        )
    return tuple(index.parent / n for n in names)


def _read_config(folder: Path) -> dict[str, Any] | None:
    """The ``config.json`` beside the weights (None when there is none): it is checked against
    the backbone, so one that cannot be read is refused, not skipped."""
    path = folder / "config.json"
    if not path.is_file():
        return None
    try:
        config = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise WeightsError(
            f"{path} is not readable JSON ({reason}): it says which model the weights are "
            "for, so it is not skipped; download it again, or move it away to load the weights "
            "unchecked"
        ) from None
    if not isinstance(config, dict):
        raise WeightsError(
            f"{path} holds a JSON {type(config).__name__}, not an object: download it again, or "
            "move it away to load the weights unchecked"
        )
    return config


def read_weights(source: WeightsSource) -> State:
    """The tensors of ``source`` by name, as stored (shards merged).

    Containers are unwrapped (``{"model": ...}``, ``{"state_dict": ...}``), a whole-model
    ``module.`` prefix (DataParallel) is removed, and of a file that holds a backbone and more
    (``backbone.*`` beside a head) only the backbone is kept.

    Raises:
        FileNotFoundError: a file disappeared.
        WeightsError: unreadable, not a dict of tensors, a claravid checkpoint, or shards that
            repeat a tensor.
    """
    state: State = {}
    for file in source.files:
        part = _read_one(file)
        twice = sorted(set(part) & set(state))
        if twice:
            raise WeightsError(f"{file} repeats {twice[:3]} of another shard: download it again")
        state.update(part)
    if state and all(k.startswith("module.") for k in state):
        state = {k.removeprefix("module."): v for k, v in state.items()}
    backbone = {
        k.removeprefix("backbone."): v for k, v in state.items() if k.startswith("backbone.")
    }
    return backbone or state


def _read_one(path: Path) -> State:
    obj = read_tensor_file(path, "weights file", WeightsError)
    if isinstance(obj, dict) and (
        str(obj.get("format", "")).startswith("claravid") or "model_args" in obj
    ):
        model_args = obj.get("model_args")
        args = model_args if isinstance(model_args, dict) else {}
        raise WeightsError(
            f"{path} is a claravid checkpoint (a trained {args.get('backbone', '')} segmenter), "
            "not backbone weights: evaluate, export or predict with it as a checkpoint "
            f"(load_checkpoint, --checkpoint {path}); as backbone weights pass the file it was "
            f"trained from ({args.get('weights')})"
        )
    for key in ("state_dict", "model", "module"):
        if isinstance(obj, dict) and isinstance(obj.get(key), dict):
            obj = obj[key]
    if not isinstance(obj, dict):
        raise WeightsError(f"{path} holds a {type(obj).__name__}, not a state dict")
    bad = [k for k, v in obj.items() if not isinstance(k, str) or not torch.is_tensor(v)]
    if bad:
        raise WeightsError(
            f"{path} is not a state dict of tensors: entries {bad[:5]} are not name -> tensor; "
            "pass backbone weights (an official .pth, a Hugging Face or timm model.safetensors)"
        )
    empty = [k for k, v in obj.items() if v.is_meta]
    if empty:
        raise WeightsError(
            f"{path} holds tensors without values (on the meta device: {', '.join(empty[:3])}"
            f"{' ...' if len(empty) > 3 else ''}), as a model built empty and saved before its "
            "weights were loaded: save the model after loading them, or download the file again"
        )
    return dict(obj)


def load_weights(
    model: nn.Module,
    spec: BackboneSpec,
    weights: str | os.PathLike | WeightsSource,
    arch: Mapping[str, Any] | None = None,
) -> None:
    """Load ``weights`` into a backbone built from ``spec`` (as built), strictly.

    Args:
        model: The backbone.
        spec: Its description.
        weights: A path, folder, hub id, ``"official"``, or a `WeightsSource`.
        arch: The arguments it was built with, when they override ``spec.arch``.

    Raises:
        FileNotFoundError: no such file.
        WeightsError: unreadable; the other family's, another size's, other pre-training
            data's; a config.json of another architecture; non-finite values; mismatched keys.
    """
    arch = dict(arch if arch is not None else spec.arch)
    overrides = {k: v for k, v in arch.items() if spec.arch.get(k) != v}
    source = weights if isinstance(weights, WeightsSource) else locate_weights(weights, spec)
    state = read_weights(source)
    family = WEIGHTS_FAMILIES[spec.family]
    check_family(state, spec, source, source.config)
    fmt = detect_format(state, family.formats)
    official = to_official(state, fmt)
    check_config(source.config, str(source), family, arch, spec)
    shape = state_shape(official, keeps_local_cls_norm=fmt is None)
    check_identity(shape, spec, overrides, source.names, source.config, str(source))
    own = model.state_dict()
    for key in absent_keys(fmt, list(own), official):
        official[key] = own[key].detach().clone()
    for key in fmt.reshape if fmt else ():
        if key in official and key in own and official[key].numel() == own[key].numel():
            official[key] = official[key].reshape(own[key].shape)
    check_values(official, str(source))
    if family.check is not None:
        family.check(official, model, str(source))
    load_state_strict(model, official, source, spec, overrides, fmt.name if fmt else "official")


def check_values(state: Mapping[str, torch.Tensor], source: str) -> None:
    """Refuse NaN or infinite values (a damaged file would give NaN features)."""
    bad = [
        k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())
    ]
    if bad:
        raise WeightsError(
            f"{source} holds NaN or infinite values in {', '.join(sorted(bad)[:5])}"
            f"{' ...' if len(bad) > 5 else ''}: the file is damaged; download it again"
        )


def load_state_strict(
    model: nn.Module,
    state: State,
    source: Any,
    spec: BackboneSpec,
    overrides: Mapping[str, Any] | None = None,
    format_name: str = "official",
) -> None:
    """Load official-key weights strictly, or raise `WeightsError` saying what differs."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = sorted(
        f"{k}: file {tuple(state[k].shape)} vs model {tuple(own[k].shape)}"
        for k in set(own) & set(state)
        if state[k].shape != own[k].shape
    )
    if missing or unexpected or shapes:
        lines = [f"weights from {source} do not match the backbone {spec.name}:"]
        if missing:
            lines.append(f"  missing keys ({len(missing)}): {', '.join(missing[:20])}")
        if unexpected:
            lines.append(f"  unexpected keys ({len(unexpected)}): {', '.join(unexpected[:20])}")
        if shapes:
            lines.append(f"  wrong shapes ({len(shapes)}): {'; '.join(shapes[:10])}")
        lines.append(f"  {_what_it_is(state, spec, overrides or {}, format_name)}")
        raise WeightsError("\n".join(lines))
    model.load_state_dict(state, strict=True)


def _what_it_is(state: State, spec: BackboneSpec, overrides: Mapping[str, Any], fmt: str) -> str:
    shape = state_shape(state, keeps_local_cls_norm=False)
    if shape is None:
        return (
            f"the file does not hold a {spec.family_name} ViT in the official, Hugging Face or "
            "timm names: pass backbone weights"
        )
    fit = [s.name for s in fitting(shape, spec.family, overrides)]
    which = f"that is {' or '.join(fit)}" if fit else "no named backbone has that shape"
    return f"the file ({fmt} names) holds a {spec.family_name} ViT {shape}: {which}"

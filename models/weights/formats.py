"""Weights formats as data: how another program's names map to the official ones, and back.

A family (DINOv2 in `claravid.models.weights.dinov2`, DINOv3 in `claravid.models.weights.dinov3`)
declares each format people download besides the official one (Hugging Face ``transformers``,
timm) as a `KeyFormat`: the renames, the tensors stored in parts (q/k/v rows), what the format
does not store, and the few changes that are not renames (declared functions). The functions
here read any declaration, in either direction; nothing else knows a format's names.

Patterns use two placeholders: ``{n}`` for a block index and ``{p}`` for ``weight``/``bias``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import torch

State = dict[str, torch.Tensor]


class WeightsError(ValueError):
    """Weights do not match the backbone (missing, unexpected or mis-shaped keys, another family,
    size or pre-training data), or cannot be read, found or fetched."""


@dataclass(frozen=True)
class Rename:
    """One official name and the format's name for the same tensor.

    Attributes:
        official: The official name (pattern).
        other: The format's name (pattern).
        ffn: Only for this feed-forward kind (``"mlp"`` or ``"swiglu"``), where the two
            spell the same name differently; None for all.
    """

    official: str
    other: str
    ffn: str | None = None


@dataclass(frozen=True)
class Split:
    """An official tensor the format stores as equal row blocks under several names.

    Attributes:
        official: The official name (pattern), e.g. ``blocks.{n}.attn.qkv.{p}``.
        parts: The format's name of each block, in row order; None for a block the format does
            not store because it is zero (DINOv3's masked key bias).
    """

    official: str
    parts: tuple[str | None, ...]


@dataclass(frozen=True)
class KeyFormat:
    """A weights format other than the official one.

    Attributes:
        name: How messages name it (``"Hugging Face"``, ``"timm"``).
        has: A key matching this regex shows the format.
        lacks: ... and, when given, no key matching this one.
        renames: Official name <-> the format's name; names not listed are the same in both.
        splits: Official tensors stored in parts.
        absent: Official names (regexes) the format does not store: taken from the model as
            built (buffers, pre-training-only tensors, biases the format dropped as zero).
        strip: Prefixes removed from a key wherever present (newer spellings).
        within: Prefixes under which a whole model keeps the backbone (a task model's file):
            when present, only those keys are read.
        reshape: Official names stored with other singleton dimensions (``[1, 1, D]`` for
            ``[1, D]``): reshaped to the model's shape.
        gated: Whether a state dict in this format has SwiGLU feed-forwards (which picks the
            ``ffn``-specific renames).
        to_official: A change made after the renames (official names in and out), or None.
        from_official: Its inverse, made before the renames.
    """

    name: str
    has: str
    lacks: str | None = None
    renames: tuple[Rename, ...] = ()
    splits: tuple[Split, ...] = ()
    absent: tuple[str, ...] = ()
    strip: tuple[str, ...] = ()
    within: tuple[str, ...] = ()
    reshape: tuple[str, ...] = ()
    gated: Callable[[Mapping[str, torch.Tensor]], bool] = lambda state: False
    to_official: Callable[[State], State] | None = None
    from_official: Callable[[State], State] | None = None

    def matches(self, keys: list[str]) -> bool:
        """Whether a state dict with these keys is in this format."""
        has, lacks = re.compile(self.has), self.lacks and re.compile(self.lacks)
        if not any(has.fullmatch(k) for k in keys):
            return False
        return not (lacks and any(lacks.fullmatch(k) for k in keys))


@dataclass(frozen=True)
class WeightsFamily:
    """What one family's weights look like in every format, declared once.

    Attributes:
        family: ``"dinov2"`` or ``"dinov3"``.
        marker: A key matching this regex (in any format) shows the family.
        formats: The formats besides the official names, detected in this order.
        hf_config: ``config.json`` keys of the Hugging Face model class -> the value the
            backbone's arguments give them (a function of the arguments); a file whose
            ``config.json`` says otherwise is another model.
        check: Family checks of a state under official names (``state, model, source``), or
            None.
        model_types: The transformers ``model_type`` values of this family's ViTs; a
            ``config.json`` naming another is another model's.
    """

    family: str
    marker: str
    formats: tuple[KeyFormat, ...]
    hf_config: Mapping[str, Callable[[Mapping[str, Any]], Any]] = field(default_factory=dict)
    check: Callable[..., None] | None = None
    model_types: tuple[str, ...] = ()


@cache
def _regex(pattern: str) -> re.Pattern[str]:
    escaped = (
        re.escape(pattern).replace(r"\{n\}", r"(?P<n>\d+)").replace(r"\{p\}", "(?P<p>weight|bias)")
    )
    return re.compile(escaped)


def _fill(pattern: str, groups: Mapping[str, str]) -> str:
    return pattern.replace("{n}", groups.get("n", "")).replace("{p}", groups.get("p", ""))


def _renames(fmt: KeyFormat, ffn: str) -> list[Rename]:
    return [r for r in fmt.renames if r.ffn in (None, ffn)]


def detect_format(
    state: Mapping[str, torch.Tensor], formats: tuple[KeyFormat, ...]
) -> KeyFormat | None:
    """The first of ``formats`` whose keys ``state`` has, or None (the official names)."""
    keys = list(state)
    return next((fmt for fmt in formats if fmt.matches(keys)), None)


def to_official(state: State, fmt: KeyFormat | None, ffn: str | None = None) -> State:
    """A state dict in ``fmt`` under official names (parts joined, missing zero parts added).

    ``fmt`` None: the names are the official ones already. ``ffn`` (``"mlp"``/``"swiglu"``)
    picks the feed-forward renames; None reads it from the state (``fmt.gated``). Keys that match
    no rule are kept unchanged, so that a strict load reports them. What the format does not
    store (``fmt.absent``) is not added here.

    Raises:
        WeightsError: a tensor stored in parts lacks one of them.
    """
    if fmt is None:
        return dict(state)
    for prefix in fmt.within:
        inside = {k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)}
        if inside:
            state = inside
    for prefix in fmt.strip:
        state = {k.removeprefix(prefix): v for k, v in state.items()}
    if ffn is None:
        ffn = "swiglu" if fmt.gated(state) else "mlp"
    renames = _renames(fmt, ffn)
    out: State = {}
    pending: dict[tuple[int, str, str], dict[int, torch.Tensor]] = {}
    for key, value in state.items():
        name = _rename_one(key, [(r.other, r.official) for r in renames])
        if name is not None:
            out[name] = value
            continue
        for s, split in enumerate(fmt.splits):
            found = _part_of(key, split)
            if found is not None:
                index, groups = found
                pending.setdefault((s, groups.get("n", ""), groups.get("p", "")), {})[index] = value
                break
        else:
            out[key] = value
    for (s, n, p), parts in sorted(pending.items()):
        split = fmt.splits[s]
        groups = {"n": n, "p": p}
        stored = [i for i, part in enumerate(split.parts) if part is not None]
        missing = [_fill(split.parts[i], groups) for i in stored if i not in parts]  # type: ignore[arg-type]
        if missing:
            raise WeightsError(
                f"the {fmt.name} file has part of {_fill(split.official, groups)} but lacks "
                f"{', '.join(missing)}: the file is incomplete, download it again"
            )
        like = parts[stored[0]]
        blocks = [parts.get(i, torch.zeros_like(like)) for i in range(len(split.parts))]
        out[_fill(split.official, groups)] = torch.cat(blocks, dim=0)
    return fmt.to_official(out) if fmt.to_official else out


def from_official(state: State, fmt: KeyFormat, ffn: str) -> State:
    """Official names -> ``fmt``'s (parts split; what the format does not store dropped)."""
    if fmt.from_official:
        state = fmt.from_official(dict(state))
    absent = [re.compile(a) for a in fmt.absent]
    renames = [(r.official, r.other) for r in _renames(fmt, ffn)]
    out: State = {}
    for key, value in state.items():
        if any(a.fullmatch(key) for a in absent):
            continue
        split = next((s for s in fmt.splits if _regex(s.official).fullmatch(key)), None)
        if split is not None:
            groups = _regex(split.official).fullmatch(key).groupdict()  # type: ignore[union-attr]
            for part, block in zip(split.parts, value.chunk(len(split.parts)), strict=True):
                if part is not None:
                    out[_fill(part, groups)] = block.clone()
            continue
        name = _rename_one(key, renames)
        out[key if name is None else name] = value
    return out


def _rename_one(key: str, pairs: list[tuple[str, str]]) -> str | None:
    for source, target in pairs:
        m = _regex(source).fullmatch(key)
        if m is not None:
            return _fill(target, m.groupdict())
    return None


def _part_of(key: str, split: Split) -> tuple[int, dict[str, str]] | None:
    for index, part in enumerate(split.parts):
        if part is not None:
            m = _regex(part).fullmatch(key)
            if m is not None:
                return index, m.groupdict()
    return None


def absent_keys(
    fmt: KeyFormat | None, own: list[str], state: Mapping[str, torch.Tensor]
) -> list[str]:
    """The model's keys that ``state`` lacks because ``fmt`` does not store them."""
    if fmt is None:
        return []
    absent = [re.compile(a) for a in fmt.absent]
    return [k for k in own if k not in state and any(a.fullmatch(k) for a in absent)]

"""What an exported ONNX file says about running it: the ``claravid`` metadata document.

``claravid-export`` writes one versioned JSON document under the ``metadata_props`` key
``claravid`` (plus a few readable ``claravid.*`` keys for tools that list the metadata), so the
file alone says how the model was evaluated (version 3 names the number format `dtype`; 2
named it `precision`)::

    {"format": "claravid-onnx", "version": 3,
     "dtype": "fp32" | "fp16" | "int8",
     "patch_size": 14, "num_classes": 8, "input_size": [630, 630] | null,
     "model_args": {... build_model arguments ...},
     "palette": {"name", "names", "colors" (K x [R, G, B]), "ignore_index"} | null,
     "normalisation": {"mean", "std", "channels": "RGB", "value_range": [0, 255],
                       "formula": "(x / 255 - mean) / std"},
     "window": {"size": [h, w], "stride": [h, w], "scale", "batch_size", "tta"} (known keys only),
     "training": {"step", "config_sha256"} (known keys only),
     "gsd": {"metres_per_pixel", "source"[, "frames"]} | null (the training images' scale)}

Lists in the document are in tensor order ([h, w]); the readable ``claravid.input_size`` is
``WxH``, like every size the project prints or parses (version 1 wrote it ``HxW``:
:func:`read_input_size` reads both).

Everything here is plain data: the models never import the data layer, so the caller passes the
palette already resolved (see ``claravid.eval.cli.export``).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

from claravid.models.backbones import specs as backbones

FORMAT = "claravid-onnx"
VERSION = 3
#: The first version whose readable ``claravid.input_size`` is WxH (version 1 wrote HxW).
WXH_SINCE = 2
KEY = "claravid"  # the metadata_props key holding the JSON document
PREFIX = "claravid."  # readable keys: claravid.patch_size, claravid.palette, ...
DTYPES = ("fp32", "fp16", "int8")

#: The input normalisation a training config without ``data.augment.mean/std`` used (the same
#: numbers as ``claravid.data.transforms.IMAGENET_MEAN/STD``; a test checks). Defined once, with the
#: backbone descriptions.
IMAGENET_MEAN = backbones.IMAGENET_MEAN
IMAGENET_STD = backbones.IMAGENET_STD


def config_get(config: Any, *keys: str) -> Any:
    """``config[k1][k2]...`` of a plain nested mapping, or None where a key is missing."""
    for key in keys:
        if not isinstance(config, Mapping) or key not in config:
            return None
        config = config[key]
    return config


def _positive_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


def _pair(value: Any) -> list[int] | None:
    """``224`` or ``[224, 280]`` as ``[h, w]``; None for anything else."""
    if _positive_int(value):
        return [value, value]
    if isinstance(value, list | tuple) and len(value) == 2 and all(map(_positive_int, value)):
        return [int(value[0]), int(value[1])]
    return None


#: The training-config keys read here (tests/train checks them against the training schema).
CONFIG_KEYS: tuple[tuple[str, ...], ...] = (
    ("val", "window"),
    ("val", "stride"),
    ("val", "scale"),
    ("val", "batch_size"),
    ("data", "augment", "mean"),
    ("data", "augment", "std"),
)


def window_from_config(config: Any) -> dict[str, Any]:
    """The validation windows of a resolved training config (``val.window/stride/scale/...``).

    Returns only the keys the config sets with a usable value: ``size`` and ``stride`` as
    ``[h, w]``, ``scale`` (float > 0), ``batch_size``, and ``tta`` (``rule``, ``scales``,
    ``flip``, ``size``: the test-time augmentation of ``val.tta_*``) when ``val.tta_scales``
    lists ratios.
    """
    out: dict[str, Any] = {}
    for name, key in (("size", "window"), ("stride", "stride")):
        pair = _pair(config_get(config, "val", key))
        if pair is not None:
            out[name] = pair
    scale = config_get(config, "val", "scale")
    if isinstance(scale, int | float) and not isinstance(scale, bool) and scale > 0:
        out["scale"] = float(scale)
    if _positive_int(config_get(config, "val", "batch_size")):
        out["batch_size"] = config_get(config, "val", "batch_size")
    scales = config_get(config, "val", "tta_scales")
    if isinstance(scales, list | tuple) and scales:  # the evaluation protocol validated with
        size = config_get(config, "val", "tta_size")
        out["tta"] = {
            "rule": str(config_get(config, "val", "tta_rule") or "dinov3"),
            "scales": [float(r) for r in scales],
            "flip": bool(config_get(config, "val", "tta_flip")),
            "size": size if _positive_int(size) else None,
        }
    return out


def backbone_statistics(model_args: Any) -> tuple[Any, Any] | None:
    """``(mean, std)`` of the backbone ``model_args`` names (its weights' statistics), or None
    for an unknown or missing name."""
    name = model_args.get("backbone") if isinstance(model_args, Mapping) else None
    spec = backbones.BACKBONES.get(name) if isinstance(name, str) else None
    return None if spec is None else (spec.mean, spec.std)


def normalisation_from_config(
    config: Any, default: tuple[Any, Any] | None = None
) -> dict[str, Any]:
    """Mean and std of the config's ``data.augment``; where it does not set them, ``default``
    (``(mean, std)``: the backbone's, `backbone_statistics`), else ImageNet's."""
    stats = {}
    mean, std = default if default is not None else (IMAGENET_MEAN, IMAGENET_STD)
    for name, default_value in (("mean", mean), ("std", std)):
        value = config_get(config, "data", "augment", name)
        ok = isinstance(value, list | tuple) and len(value) == 3
        ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        stats[name] = [float(v) for v in (value if ok else default_value)]
    return {
        **stats,
        "channels": "RGB",
        "value_range": [0, 255],
        "formula": "(x / 255 - mean) / std",
    }


def config_hash(config: Any) -> str | None:
    """SHA-256 of the resolved config as canonical JSON (sorted keys); None without a config."""
    if not isinstance(config, Mapping):
        return None
    text = json.dumps(config, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def build_metadata(
    model_args: Mapping[str, Any],
    *,
    patch_size: int,
    num_classes: int,
    input_size: tuple[int, int] | None = None,
    dtype: str = "fp32",
    config: Mapping[str, Any] | None = None,
    step: int | None = None,
    palette: Mapping[str, Any] | None = None,
    statistics: tuple[Any, Any] | None = None,
    gsd: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``claravid`` document for an export.

    Args:
        model_args: The model's ``build_model`` arguments.
        patch_size: The backbone's patch size.
        num_classes: K, the logits' channels.
        input_size: (H, W) of a fixed-size export; None when H and W are dynamic.
        dtype: the file's number format, ``fp32``, ``fp16`` or ``int8``.
        config: The checkpoint's resolved training config (windows, normalisation, hash); a
            config without ``data.augment.mean/std`` records the backbone's statistics.
        step: The training step the checkpoint was written at.
        palette: ``{"name", "names", "colors", "ignore_index"}`` (plain lists), or None.
        statistics: ``(mean, std)`` the model normalises with when the config records none
            (a segmenter's ``mean``/``std``); None: its backbone's.
        gsd: the checkpoint's ground sampling distance record (metres per pixel of the training
            images, ``claravid.data.gsd``), or None when training recorded none.
    """
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    training: dict[str, Any] = {}
    if _positive_int(step) or step == 0:
        training["step"] = int(step)  # type: ignore[arg-type]  # an int, checked just above
    digest = config_hash(config)
    if digest is not None:
        training["config_sha256"] = digest
    return {
        "format": FORMAT,
        "version": VERSION,
        "dtype": dtype,
        "patch_size": int(patch_size),
        "num_classes": int(num_classes),
        "input_size": list(input_size) if input_size is not None else None,
        "model_args": dict(model_args),
        "palette": _plain_palette(palette) if palette is not None else None,
        # The model owns its statistics: a config that records none gets the model's.
        "normalisation": normalisation_from_config(
            config, statistics or backbone_statistics(model_args)
        ),
        "window": window_from_config(config),
        "training": training,
        "gsd": dict(gsd) if gsd is not None else None,
    }


def _plain_palette(palette: Mapping[str, Any]) -> dict[str, Any]:
    names = [str(n) for n in palette["names"]]
    colors = [[int(c) for c in color] for color in palette["colors"]]
    if len(colors) != len(names) or any(len(c) != 3 for c in colors):
        raise ValueError("palette needs one [R, G, B] colour per class name")
    return {
        "name": str(palette.get("name") or ""),
        "names": names,
        "colors": colors,
        "ignore_index": int(palette.get("ignore_index", 255)),
    }


def metadata_props(document: Mapping[str, Any]) -> dict[str, str]:
    """The ``metadata_props`` entries: the document, and readable copies of its main fields."""
    props = {
        KEY: json.dumps(document, separators=(",", ":")),
        PREFIX + "patch_size": str(document["patch_size"]),
        PREFIX + "num_classes": str(document["num_classes"]),
        PREFIX + "model_args": json.dumps(document["model_args"]),
        PREFIX + "dtype": document["dtype"],
    }
    if document.get("input_size"):
        height, width = document["input_size"]
        props[PREFIX + "input_size"] = f"{width}x{height}"  # WxH, the project's convention
    if document.get("palette"):
        props[PREFIX + "palette"] = document["palette"]["name"]
    if document.get("window"):
        props[PREFIX + "window"] = json.dumps(document["window"])
    return props


def read_metadata(props: Mapping[str, str]) -> dict[str, Any] | None:
    """The ``claravid`` document of a file's metadata map; None when absent or unreadable.

    Raises:
        ValueError: the document comes from a newer claravid (a version we cannot read).
    """
    text = props.get(KEY)
    if not text:
        return None
    try:
        document = json.loads(text)
    except json.JSONDecodeError:
        return None
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        return None
    if not isinstance(document.get("version"), int) or document["version"] > VERSION:
        raise ValueError(
            f"ONNX metadata version {document.get('version')!r} is newer than this claravid "
            f"reads ({VERSION}); upgrade claravid"
        )
    return document


def read_input_size(props: Mapping[str, str]) -> tuple[int, int] | None:
    """The fixed input size ``(height, width)`` of a file's metadata map; None when dynamic.

    The document's ``input_size`` ([h, w]) first; else the readable ``claravid.input_size``,
    ``WxH`` from version 2 on and ``HxW`` in version-1 files (and in files without a document,
    which only version 1 wrote).
    """
    document = read_metadata(props)
    if document is not None and document.get("input_size"):
        height, width = document["input_size"]
        return int(height), int(width)
    text = props.get(PREFIX + "input_size")
    if not text:
        return None
    first, second = (int(v) for v in text.lower().split("x"))
    version = document.get("version", 1) if document is not None else 1
    return (second, first) if version >= WXH_SINCE else (first, second)

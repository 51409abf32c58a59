"""Palettes: a target taxonomy (train ids, names, colours) and the reduction onto it.

A palette is a YAML file (see ``configs/palettes/``), loaded by name or by path::

    name: uavid
    ignore_index: 255
    classes:                      # train ids 0..K-1
      - {id: 0, name: Clutter, color: [0, 0, 0]}
      ...
    mapping:                      # every ClaraVid class -> a palette class, or `ignore`
      Vehicles: Static car
      ...
    dynamic:                      # optional: overrides for pixels marked dynamic
      Vehicles: Moving car

Without ``mapping`` each ClaraVid class maps to the palette class of the same name. The
reduction is one 256-entry lookup table over label codes (``claravid.io.labels``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from claravid.data.ignore import IGNORE_INDEX
from claravid.data.real_classes import NATIVE, RealMap
from claravid.data.real_classes import color_indices as color_indices  # re-exported
from claravid.infra.resources import shipped_file, shipped_names
from claravid.io.labels import DYNAMIC_OFFSET
from claravid.io.layout import CLASSES, UNLABELED_ID
from claravid.io.yamlfile import YamlFileError, load_yaml

IGNORE = "ignore"


class PaletteError(ValueError):
    """A palette file is malformed; the message names the file and the entry."""


@dataclass(frozen=True)
class Palette:
    """A target label set and the lookup table from ClaraVid label codes to its train ids.

    Attributes:
        name: the palette's name.
        names: class names in train-id order.
        colors: uint8 K×3 RGB colours in train-id order.
        lut: uint8[256], label code -> train id (``ignore_index`` where ignored).
        ignore_index: the train id of ignored pixels (255).
        uses_dynamic: whether the reduction reads the dynamic mask.
        real: the real side: real dataset name -> how its native classes map onto this
            palette (empty for a palette that names no real dataset).
        no_analogue: ClaraVid class -> the palette's stated rule for it, where the class has
            no counterpart in the real datasets (e.g. GreenEnergy).
    """

    name: str
    names: tuple[str, ...]
    colors: np.ndarray
    lut: np.ndarray
    ignore_index: int = IGNORE_INDEX
    uses_dynamic: bool = False
    real: Mapping[str, RealMap] = field(default_factory=dict)
    no_analogue: Mapping[str, str] = field(default_factory=dict)

    @property
    def num_classes(self) -> int:
        return len(self.names)

    def remap(self, codes: np.ndarray) -> np.ndarray:
        """Label codes (uint8) -> train ids (uint8), in one table lookup."""
        codes = np.asarray(codes, dtype=np.uint8)
        if codes.size == 0:
            return codes.copy()
        return cv2.LUT(codes, self.lut)  # ~10× numpy's fancy indexing on a full frame

    def ids_from_colors(self, rgb: np.ndarray) -> np.ndarray:
        """A colour-coded label image (uint8 H×W×3 RGB) -> train ids; other colours -> ignore."""
        return color_indices(rgb, self.colors, missing=self.ignore_index)

    @property
    def datasets(self) -> tuple[str, ...]:
        """The real datasets whose labels this palette decodes (its ``real:`` side)."""
        return tuple(self.real)

    def real_map(self, dataset: str) -> RealMap | None:
        """How ``dataset``'s native classes map onto this palette, or None."""
        return self.real.get(dataset)

    def colorize(self, train_ids: np.ndarray) -> np.ndarray:
        """Train ids -> uint8 RGB image; ignored pixels black."""
        table = np.zeros((256, 3), dtype=np.uint8)
        table[: self.num_classes] = self.colors
        return table[np.asarray(train_ids, dtype=np.int64).clip(0, 255)]


def _is_int(value: Any) -> bool:
    # YAML reads `true` as a bool, which Python counts as an int; 1.5 or "7" are not ids.
    return isinstance(value, int) and not isinstance(value, bool)


def _fail(source: str, message: str) -> PaletteError:
    return PaletteError(f"palette {source}: {message}")


def _parse_classes(entries: Any, source: str) -> tuple[list[str], np.ndarray]:
    if not isinstance(entries, list) or not entries:
        raise _fail(source, "'classes' must be a non-empty list of {id, name, color}")
    by_id: dict[int, tuple[str, list[int]]] = {}
    seen_names: set[str] = set()
    for number, entry in enumerate(entries, 1):
        if not isinstance(entry, dict) or {"id", "name", "color"} - entry.keys():
            raise _fail(source, f"class entry {number} {entry!r} needs 'id', 'name' and 'color'")
        class_id, name, color = entry["id"], entry["name"], entry["color"]
        if not isinstance(name, str) or not name.strip():
            raise _fail(source, f"class entry {number} has name {name!r}; give a non-empty name")
        if not _is_int(class_id) or not 0 <= class_id < IGNORE_INDEX:
            raise _fail(source, f"class {name!r} has id {class_id!r}; use an integer 0..254")
        if class_id in by_id:
            raise _fail(source, f"duplicate id {class_id} ({by_id[class_id][0]!r} and {name!r})")
        if name in seen_names:
            raise _fail(source, f"duplicate class name {name!r}")
        if not (
            isinstance(color, list)
            and len(color) == 3
            and all(_is_int(c) and 0 <= c <= 255 for c in color)
        ):
            raise _fail(
                source, f"class {name!r} colour {color!r} is not [R, G, B], integers in 0..255"
            )
        by_id[class_id] = (name, color)
        seen_names.add(name)
    if sorted(by_id) != list(range(len(by_id))):
        raise _fail(
            source, f"class ids must be 0..{len(by_id) - 1} without gaps, got {sorted(by_id)}"
        )
    names = [by_id[i][0] for i in range(len(by_id))]
    colors = np.asarray([by_id[i][1] for i in range(len(by_id))], dtype=np.uint8)
    return names, colors


def _parse_mapping(
    mapping: Any, names: list[str], source: str, section: str, require_all: bool
) -> dict[str, int]:
    """ClaraVid class name -> train id (or ignore), validated against both class tables."""
    claravid_names = [c.name for c in CLASSES if c.id != UNLABELED_ID]
    if mapping is None:
        mapping = {n: n for n in claravid_names} if require_all else {}
    if not isinstance(mapping, dict):
        raise _fail(source, f"'{section}' must map ClaraVid class names to palette class names")
    train_id = {name: i for i, name in enumerate(names)}
    resolved: dict[str, int] = {}
    for src, dst in mapping.items():
        if src not in claravid_names:
            raise _fail(
                source,
                f"'{section}' entry {src!r}: not a ClaraVid class ({', '.join(claravid_names)})",
            )
        if not isinstance(dst, str):
            raise _fail(source, f"'{section}' entry {src!r}: {dst!r} is not a palette class name")
        if dst == IGNORE:
            resolved[src] = IGNORE_INDEX
        elif dst in train_id:
            resolved[src] = train_id[dst]
        else:
            raise _fail(
                source,
                f"'{section}' entry {src!r}: {dst!r} is not a class of this palette "
                f"({', '.join(names)}) nor '{IGNORE}'",
            )
    unmapped = [n for n in claravid_names if n not in resolved]
    if require_all and unmapped:
        raise _fail(
            source, f"'{section}' leaves {unmapped} unmapped; map each to a class or '{IGNORE}'"
        )
    return resolved


def _real_entry(entry: Any, key: str, dataset: str, source: str) -> tuple[str, Any]:
    """One ``{name, id | color, to}`` entry of the real side, checked against the dataset's
    published table; returns (native name, target)."""
    table = NATIVE[dataset]
    if not isinstance(entry, dict) or {"name", "to"} - entry.keys():
        raise _fail(source, f"{key}: {entry!r} needs 'name', 'to' and the class's 'id' or 'color'")
    extra = set(entry) - {"name", "id", "color", "to"}
    if extra:
        raise _fail(source, f"{key}: unknown key(s) {sorted(extra)}")
    name = entry["name"]
    native = table.get(name) if isinstance(name, str) else None
    if native is None:
        raise _fail(
            source,
            f"{key}: {table.title} has no class {name!r} (its classes: {', '.join(table.names)})",
        )
    if "id" not in entry and "color" not in entry:
        raise _fail(source, f"{key} ({name}): give its 'id' or its 'color' as {table.title} does")
    if "id" in entry and entry["id"] != native.id:
        published = "no ids" if native.id is None else f"id {native.id}"
        raise _fail(
            source, f"{key} ({name}): id {entry['id']!r}, but {table.title} gives {published}"
        )
    if "color" in entry and (
        not isinstance(entry["color"], list) or tuple(entry["color"]) != native.color
    ):
        published = "no colours" if native.color is None else f"colour {list(native.color)}"
        raise _fail(
            source,
            f"{key} ({name}): colour {entry['color']!r}, but {table.title} gives {published}",
        )
    return name, entry["to"]


def _parse_real_dataset(entries: Any, dataset: str, names: list[str], source: str) -> RealMap:
    """``real.<dataset>``: a list of native classes, each to a palette class or ``ignore``."""
    table = NATIVE[dataset]
    if not isinstance(entries, list) or not entries:
        raise _fail(source, f"real.{dataset} must list {table.title}'s classes, each with 'to'")
    train_id = {name: i for i, name in enumerate(names)}
    targets: dict[str, int] = {}
    colors: dict[tuple[Any, ...], str] = {}
    for number, entry in enumerate(entries, 1):
        key = f"real.{dataset} entry {number}"
        if isinstance(entry, dict) and isinstance(entry.get("color"), list):
            color = tuple(entry["color"])
            if color in colors:
                raise _fail(
                    source,
                    f"{key}: colour {list(color)} listed twice ({colors[color]!r} and "
                    f"{entry.get('name')!r}); a colour is one class",
                )
            colors[color] = str(entry.get("name"))
        name, target = _real_entry(entry, key, dataset, source)
        if target != IGNORE and target not in train_id:
            raise _fail(
                source,
                f"{key} ({name}): {target!r} is not a class of this palette "
                f"({', '.join(names)}) nor '{IGNORE}'",
            )
        resolved = UNLABELED_ID if target == IGNORE else train_id[target]
        if name in targets:
            first = IGNORE if targets[name] == UNLABELED_ID else names[targets[name]]
            raise _fail(
                source, f"{key}: {table.title} class {name!r} given twice ({first} and {target})"
            )
        targets[name] = resolved
    unmapped = [n for n in table.names if n not in targets]
    if unmapped:
        raise _fail(
            source,
            f"real.{dataset} leaves {table.title}'s {unmapped} unmapped; map each to a class "
            f"or '{IGNORE}'",
        )
    return RealMap(dataset, targets)


def _parse_real(section: Any, names: list[str], source: str) -> dict[str, RealMap]:
    if section is None:
        return {}
    if not isinstance(section, dict):
        raise _fail(source, f"'real' must map dataset names ({', '.join(NATIVE)}) to class lists")
    unknown = [d for d in section if d not in NATIVE]
    if unknown:
        raise _fail(
            source, f"real: unknown dataset(s) {unknown}; the toolkit reads {', '.join(NATIVE)}"
        )
    return {d: _parse_real_dataset(section[d], d, names, source) for d in section}


def _parse_no_analogue(section: Any, source: str) -> dict[str, str]:
    """``no_analogue``: ClaraVid class -> the rule chosen for it, in words."""
    if section is None:
        return {}
    claravid_names = {c.name for c in CLASSES if c.id != UNLABELED_ID}
    if not isinstance(section, dict):
        raise _fail(source, "'no_analogue' must map ClaraVid class names to the rule chosen")
    for name, rule in section.items():
        if name not in claravid_names:
            raise _fail(source, f"no_analogue entry {name!r}: not a ClaraVid class")
        if not isinstance(rule, str) or not rule.strip():
            raise _fail(source, f"no_analogue entry {name!r}: state the rule chosen, in words")
    return dict(section)


def palette_from_dict(config: dict[str, Any], source: str = "<dict>") -> Palette:
    """Build a palette from its parsed YAML content (see the module docstring)."""
    if not isinstance(config, dict):
        raise _fail(source, "expected a mapping with 'name' and 'classes'")
    known_keys = {"name", "ignore_index", "classes", "mapping", "dynamic", "real", "no_analogue"}
    unknown_keys = set(config) - known_keys
    if unknown_keys:
        raise _fail(source, f"unknown key(s) {sorted(unknown_keys)}")
    if "name" in config and (not isinstance(config["name"], str) or not config["name"].strip()):
        raise _fail(source, f"'name' is {config['name']!r}; give the palette a non-empty name")
    if config.get("ignore_index", IGNORE_INDEX) != IGNORE_INDEX:
        raise _fail(source, f"ignore_index must be {IGNORE_INDEX}")
    names, colors = _parse_classes(config.get("classes"), source)
    static = _parse_mapping(config.get("mapping"), names, source, "mapping", require_all=True)
    dynamic = _parse_mapping(config.get("dynamic"), names, source, "dynamic", require_all=False)

    lut = np.full(256, IGNORE_INDEX, dtype=np.uint8)
    for cls in CLASSES:
        if cls.id == UNLABELED_ID:
            continue
        lut[cls.id] = static[cls.name]
        lut[cls.id + DYNAMIC_OFFSET] = dynamic.get(cls.name, static[cls.name])
    lut.setflags(write=False)
    colors.setflags(write=False)
    real = _parse_real(config.get("real"), names, source)
    no_analogue = _parse_no_analogue(config.get("no_analogue"), source)
    return Palette(
        name=str(config.get("name", Path(source).stem)),
        names=tuple(names),
        colors=colors,
        lut=lut,
        uses_dynamic=bool(dynamic),
        real=real,
        no_analogue=no_analogue,
    )


def available_palettes() -> list[str]:
    """Names of the palettes shipped in ``configs/palettes`` (installed with the package)."""
    return shipped_names("palettes")


def load_palette(palette: str | Path | Palette) -> Palette:
    """Load a palette by name (``claravid``, ``uavid``) or from a YAML file path."""
    if isinstance(palette, Palette):
        return palette
    path = Path(palette)
    if path.suffix not in (".yaml", ".yml"):
        shipped = shipped_file(str(palette), "palettes")
        if shipped is None:
            raise PaletteError(
                f"unknown palette {str(palette)!r}: shipped palettes are "
                f"{', '.join(available_palettes())}; or pass the path of a YAML file"
            )
        path = Path(str(shipped))
    if not path.is_file():
        raise PaletteError(f"palette file not found: {path}")
    try:
        config = load_yaml(path)
    except YamlFileError as error:
        raise PaletteError(f"palette {error}") from None
    return palette_from_dict(config, str(path))

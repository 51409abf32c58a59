"""Reading YAML files strictly: a key given twice, or a binary file, is an error naming it.

PyYAML's ``safe_load`` lets the last of two equal keys win silently, so a palette that maps
``Building`` twice would quietly use the second line. ``load_yaml`` reads with a SafeLoader
that refuses duplicate keys at any depth and names the key and both lines.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

_MERGE_TAG = "tag:yaml.org,2002:merge"


class YamlFileError(ValueError):
    """A YAML file cannot be used; the message names the file and the place."""


class StrictSafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that raises on a mapping key given twice."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, yaml.Mark] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_TAG:  # `<<: *anchor` merges, it is not a key
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: the base class reports it
                    continue
                if first is not None:
                    raise yaml.constructor.ConstructorError(
                        f"while constructing a mapping (line {first.line + 1})",
                        first,
                        f"duplicate key {key!r} (first on line {first.line + 1}, again on "
                        f"line {key_node.start_mark.line + 1}); keep one",
                        key_node.start_mark,
                    )
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, source: str = "<string>") -> Any:
    """Parse YAML text strictly; errors name ``source``."""
    try:
        return yaml.load(text, Loader=StrictSafeLoader)
    except yaml.constructor.ConstructorError as error:
        if error.problem and error.problem.startswith("duplicate key"):
            raise YamlFileError(f"{source}: {error.problem}") from None
        raise YamlFileError(f"{source}: not valid YAML ({error})") from None
    except yaml.YAMLError as error:
        raise YamlFileError(f"{source}: not valid YAML ({error})") from None


def load_yaml(path: str | os.PathLike[str]) -> Any:
    """Read a YAML file strictly (no duplicate keys, text only).

    Raises:
        FileNotFoundError: the file does not exist.
        YamlFileError: binary content, invalid YAML, or a key given twice; the message names
            the file, and the key and its lines.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"YAML file not found: {path}")
    data = path.read_bytes()
    try:
        if b"\x00" in data:
            raise UnicodeDecodeError("utf-8", data, data.index(b"\x00"), len(data), "NUL byte")
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise YamlFileError(
            f"{path}: not a YAML text file (binary data at byte {error.start}); pass a .yaml file"
        ) from None
    return parse_yaml(text, str(path))

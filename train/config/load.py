"""Loading a training config: the typed defaults, then one YAML file (a path or a shipped name),
then dotted ``key=value`` overrides, merged by OmegaConf; every problem one `ConfigError` naming
the file or the key."""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException

from claravid.data.transforms import statistics_problem
from claravid.infra.resources import shipped_file, shipped_names
from claravid.train.config.checks import check_config, resolve_backbone
from claravid.train.config.schema import Config, ConfigError, to_plain, valid_keys


def _unknown_key(full_key: str) -> ConfigError:
    close = difflib.get_close_matches(full_key, valid_keys(), n=3, cutoff=0.6)
    leaf = full_key.rsplit(".", 1)[-1]
    close += [k for k in valid_keys() if k.rsplit(".", 1)[-1] == leaf and k not in close]
    hint = f"; did you mean {' or '.join(close[:3])}?" if close else ""
    return ConfigError(f"unknown config key {full_key!r}{hint}")


def find_config(name: str | Path) -> tuple[Path | None, str]:
    """(path, text) of a config file path or a shipped config name."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise ConfigError(f"config file {path} not found")
        return path, _read_text(path)
    entry = shipped_file(str(name))
    if entry is None:
        raise ConfigError(
            f"no config file {name} and no shipped config named {name!r}; "
            f"shipped: {', '.join(n for n in shipped_names() if n != 'augment')}"
        )
    return None, entry.read_text(encoding="utf-8")


def _read_text(path: Path) -> str:
    """A config file's text; a binary file is refused by name."""
    data = path.read_bytes()
    try:
        if b"\x00" in data:
            raise UnicodeDecodeError("utf-8", data, data.index(b"\x00"), len(data), "NUL byte")
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"config {path} is not a YAML text file (binary data at byte {exc.start}); "
            "pass a .yaml file or a shipped config name"
        ) from None


def _check_loaded(loaded: Any, source: str) -> DictConfig:
    """The file is a mapping of sections, each section a mapping (as the schema has it): the
    file's config, checked."""
    if not isinstance(loaded, DictConfig):
        kind = "a list" if isinstance(loaded, ListConfig) else "no mapping"
        raise ConfigError(
            f"{source} holds {kind}, not a mapping of sections (out_dir:, data:, model:, "
            "train:, val:, log:)"
        )
    schema = OmegaConf.structured(Config)
    for key in loaded:
        section = str(key)
        node = schema._get_node(section) if section in schema else None
        value = loaded._get_node(key)
        if isinstance(node, DictConfig) and not isinstance(value, DictConfig):
            got = to_plain(loaded, resolve=False)[section]
            raise ConfigError(
                f"{source}: section {section} must be a mapping of keys, e.g. "
                f"{section}: {{{next(iter(node))!s}: ...}}; got {got!r}"
            )
    return loaded


def _merge(base: DictConfig, other: Any, source: str) -> DictConfig:
    try:
        merged = OmegaConf.merge(base, other)
    except ConfigKeyError as exc:
        raise _unknown_key(str(exc.full_key)) from None
    except OmegaConfBaseException as exc:
        key = getattr(exc, "full_key", None)
        msg = str(exc).splitlines()[0]
        raise ConfigError(f"bad value for {key} ({source}): {msg}") from None
    return merged  # type: ignore[return-value]  # a structured config merges into a DictConfig


def load_config(name: str | Path, overrides: list[str] | tuple[str, ...] | str = ()) -> DictConfig:
    """Defaults, then the YAML file (path or shipped name), then ``key=value`` overrides.

    ``overrides`` is a list of ``key=value`` strings, or one string of them separated by spaces.

    Raises:
        ConfigError: unknown key, bad value, missing required key, unreadable file, a file
            that is not a mapping of sections (a list, a single value, binary data).
    """
    cfg = OmegaConf.structured(Config)
    path, text = find_config(name)
    source = f"config {path or name}"
    try:
        loaded = OmegaConf.create(text) if text.strip() else OmegaConf.create({})
    except Exception as exc:  # a YAML syntax error, or a bare scalar: name the file
        if not isinstance(_safe_load(text), (dict, list)):
            raise ConfigError(
                f"{source} holds a single value, not a mapping of sections (out_dir:, data:, "
                "model:, train:, val:, log:)"
            ) from None
        raise ConfigError(f"cannot parse {source}: {exc}") from None
    sections = _check_loaded(loaded, source)
    _check_statistics_given(sections, source)
    _one_item_lists(cfg, sections)
    cfg = _merge(cfg, sections, source)
    if isinstance(overrides, str):  # "train.steps=5 val.every=0": one string, split on spaces
        overrides = overrides.split()
    bad = [o for o in overrides if "=" not in o or o.startswith("=")]
    if bad:
        raise ConfigError(f"override {bad[0]!r} is not key=value (e.g. train.steps=100)")
    given = OmegaConf.from_dotlist(list(overrides))
    _check_statistics_given(given, "command line")
    _one_item_lists(cfg, given)
    cfg = _merge(cfg, given, "command line")
    check_config(cfg)
    resolve_backbone(cfg)
    return cfg


def from_plain(data: dict[str, Any]) -> DictConfig:
    """A config back from `to_plain` (a checkpoint's), checked against the schema."""
    return _merge(OmegaConf.structured(Config), data, "checkpoint")


def _check_statistics_given(given: DictConfig, source: str) -> None:
    """``data.augment.mean/std`` as given must be three numbers each (or null): said here, by
    key, instead of OmegaConf's "bad value for None ... '$VALUE'" from the merge."""
    augment = given.get("data", {}).get("augment", {}) if "data" in given else {}
    if not isinstance(augment, DictConfig):
        return  # not a mapping: _check_loaded and the merge name it
    for name in ("mean", "std"):
        if name not in augment:
            continue
        container = OmegaConf.to_container(augment, resolve=False)
        if not isinstance(container, dict):  # a DictConfig always converts to a dict
            raise TypeError(f"data.augment converted to a {type(container).__name__}, not a dict")
        value = container[name]
        if value is None or _three_numbers(value):
            continue  # the merge converts them; check_config checks their values
        problem = statistics_problem(value if name == "mean" else None,
                                     value if name == "std" else None)  # fmt: skip
        raise ConfigError(f"bad value for data.augment.{problem} ({source})")


def _three_numbers(value: Any) -> bool:
    if (
        not isinstance(value, list | tuple)
        or len(value) != 3
        or any(isinstance(v, bool) for v in value)
    ):
        return False
    try:
        [float(v) for v in value]
    except (TypeError, ValueError):
        return False
    return True


def _one_item_lists(schema: DictConfig, given: DictConfig) -> None:
    """A single value where the schema has a list is a list of one, in place
    (``data.split.test_missions=urban_high_1``, as ``SplitConfig`` takes a single string)."""
    for key in list(given.keys()):
        if key not in schema:
            continue  # an unknown key: _merge names it
        node, value = schema._get_node(str(key)), given._get_node(key)
        if isinstance(node, DictConfig) and isinstance(value, DictConfig):
            _one_item_lists(node, value)
        elif isinstance(node, ListConfig) and not isinstance(value, (ListConfig, DictConfig)):
            item = given[key]
            if item is not None:
                given[key] = [item]


def _safe_load(text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return {}  # a syntax error: reported as such by the caller

"""The units images belong to: what ``--group-by`` makes rows of and ``--cluster`` resamples.

ClaraVid images have a ``mission``, a ``viewpoint`` (mission + altitude/direction folder) and a
spatial ``block`` (the block of the split, from the extrinsics); UAVid images a ``sequence``
(``seqN``); every image its parent ``folder`` relative to the data root, and is its own
``image``. An evaluation stores each image's units (``attributes``: unit -> one label per
image) so a saved report can be regrouped or bootstrapped by any of them without the data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

#: The kinds of data an evaluation reads (``--dataset``).
DATASETS = ("claravid", "uavid", "udd5", "udd6", "vdd", "aeroscapes", "icg", "folder")
#: The real datasets read by their own layout (``claravid.data.real_layouts``).
_LAID_OUT = ("udd5", "udd6", "vdd", "aeroscapes", "icg")
#: Units by dataset kind (``block`` only where extrinsics exist; ``image`` always).
UNITS: dict[str, tuple[str, ...]] = {
    "claravid": ("mission", "viewpoint", "block", "folder"),
    "uavid": ("sequence", "folder"),
    "folder": ("folder",),
    **dict.fromkeys(_LAID_OUT, ("folder",)),
}
#: What ``--group-by`` accepts (rows of the report).
GROUP_BY = ("mission", "viewpoint", "sequence", "folder")
#: What ``--cluster`` accepts (resampled together by the bootstrap).
CLUSTER_UNITS = ("image", "viewpoint", "mission", "block", "sequence", "folder")
#: The default cluster per dataset kind, then the fallbacks when it is not stored.
DEFAULT_CLUSTER = {"claravid": "block", "uavid": "sequence", "folder": "folder",
                   **dict.fromkeys(_LAID_OUT, "image")}  # fmt: skip
_FALLBACK_CLUSTERS = ("block", "sequence", "viewpoint", "folder", "image")
_NEEDS = {"mission": "ClaraVid", "viewpoint": "ClaraVid", "block": "ClaraVid with extrinsics",
          "sequence": "UAVid"}  # fmt: skip


class UnitError(ValueError):
    """The images do not have the unit asked for (a user's mistake: one line, exit 2)."""


def available_units(attributes: Mapping[str, Sequence[str]]) -> list[str]:
    """The units images with these ``attributes`` carry (``image`` always)."""
    return ["image", *(a for a in attributes if any(attributes[a]))]


def check_unit(attributes: Mapping[str, Sequence[str]], unit: str, flag: str = "--cluster") -> str:
    """Return ``unit`` if images with these ``attributes`` carry it.

    Raises:
        UnitError: they do not (e.g. ``block`` without extrinsics); the message lists theirs.
    """
    units = available_units(attributes)
    if unit not in units:
        where = f" ({_NEEDS[unit]} data)" if unit in _NEEDS else ""
        raise UnitError(
            f"{flag} {unit} is not available for these images{where}; they have: {', '.join(units)}"
        )
    return unit


def unit_labels(
    paths: Sequence[str],
    attributes: Mapping[str, Sequence[str]],
    unit: str,
    flag: str = "--cluster",
) -> list[str]:
    """The label of each image for ``unit``.

    ``viewpoint`` is the mission and viewpoint folder together (the same viewpoint of two
    missions is two units); ``image`` makes every image its own unit.

    Raises:
        UnitError: these images have no such unit (e.g. ``block`` without extrinsics).
    """
    if check_unit(attributes, unit, flag) == "image":
        return [str(p) for p in paths]
    if unit == "viewpoint" and "mission" in attributes:
        pairs = zip(attributes["mission"], attributes["viewpoint"], strict=True)
        return [f"{m}/{v}" for m, v in pairs]
    return list(attributes[unit])


def group_indices(
    paths: Sequence[str], attributes: Mapping[str, Sequence[str]], by: str
) -> dict[str, list[int]]:
    """Image indices per label of unit ``by`` (``--group-by``), groups sorted by label.

    Raises:
        UnitError: ``by`` is not a ``--group-by`` unit, or these images do not have it.
    """
    if by not in GROUP_BY:
        raise UnitError(f"unknown --group-by {by!r}; use one of {', '.join(GROUP_BY)}")
    out: dict[str, list[int]] = {}
    for index, label in enumerate(unit_labels(paths, attributes, by, "--group-by")):
        out.setdefault(label, []).append(index)
    return dict(sorted(out.items()))


def default_cluster(dataset: str, attributes: Mapping[str, Sequence[str]]) -> str:
    """The dataset's default cluster unit, or the first fallback the images carry."""
    units = available_units(attributes)
    wanted = DEFAULT_CLUSTER.get(dataset)
    if wanted in units:
        return wanted
    return next(u for u in _FALLBACK_CLUSTERS if u in units)

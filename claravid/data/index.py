"""Listing ClaraVid frames: which files make up each frame of a selection.

A frame is one ``<stem>`` present in every requested modality folder of one viewpoint.
Frames are listed as the official SDK lists them: mission by mission (in the requested
order), then altitude, then direction, then sorted file name.

Selection follows the SDK, which lists what exists: a key left at its default (None) means
"every one present on disk", so a partial download (one altitude, one direction, a few
missions) just works; a key named explicitly that matches no folder at all is an error that
names what exists. Listing is symmetric across the requested modalities: a stem present in
one modality folder and absent from another is an error naming the missing file (or, with
``skip_incomplete=True``, that frame is left out and counted in one warning).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from claravid.infra.errors import DatasetNotFoundError
from claravid.io.layout import (
    ALTITUDES,
    DIRECTIONS,
    MISSIONS,
    MODALITIES,
    canonical_mission,
    frame_file,
    viewpoint_folder,
)

_GET_DATA = "Download ClaraVid and pass the folder that holds the mission folders (001_rural_1 …)"

#: Viewpoint folder name -> (altitude key, direction key), e.g. ``45deg_low_h -> (low, h)``.
_VIEWPOINTS: dict[str, tuple[str, str]] = {
    viewpoint_folder(a, d): (a, d) for a in ALTITUDES for d in DIRECTIONS
}


@dataclass(frozen=True)
class Frame:
    """One frame: where it sits in the dataset and the file of each requested modality."""

    mission: str
    altitude: str
    direction: str
    stem: str
    paths: dict[str, Path] = field(compare=False, hash=False)

    @property
    def viewpoint(self) -> str:
        """The viewpoint folder name, e.g. ``45deg_low_h``."""
        return viewpoint_folder(self.altitude, self.direction)

    @property
    def key(self) -> str:
        """A stable identifier: ``<mission folder>/<viewpoint>/<stem>``."""
        return f"{MISSIONS[self.mission]}/{self.viewpoint}/{self.stem}"


def choose_keys(
    requested: Sequence[str] | str | None, valid: Mapping[str, object], what: str
) -> list[str]:
    """Validate a selection of keys: None -> every valid key; one string -> that one key.

    Duplicates are dropped (keeping the first), so no frame is listed twice.

    Raises:
        ValueError: an unknown key (the message lists the valid ones), or an empty selection.
    """
    if requested is None:
        return list(valid)
    if isinstance(requested, str):
        requested = [requested]
    requested = list(dict.fromkeys(requested))
    if not requested:
        raise ValueError(f"no {what} selected; pass None for all, or some of {', '.join(valid)}")
    unknown = [r for r in requested if r not in valid]
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; valid: {', '.join(valid)}")
    return requested


def _stems(folder: Path, suffix: str) -> set[str]:
    with os.scandir(folder) as entries:
        return {e.name[: -len(suffix)] for e in entries if e.name.endswith(suffix)}


def _viewpoints(mission_dir: Path, file_fields: Sequence[str]) -> set[str]:
    """Viewpoint folders present in any requested modality folder of a mission."""
    found: set[str] = set()
    for key in file_fields:
        with os.scandir(MODALITIES[key].folder_in(mission_dir)) as entries:
            found |= {e.name for e in entries if e.name in _VIEWPOINTS and e.is_dir()}
    return found


def _check_explicit(
    requested: Sequence[str] | str | None,
    position: int,
    what: str,
    present: dict[str, set[str]],
    root: Path,
) -> None:
    """An explicitly named altitude/direction must match at least one viewpoint folder."""
    if requested is None:
        return
    on_disk = {_VIEWPOINTS[v][position] for views in present.values() for v in views}
    for key in [requested] if isinstance(requested, str) else requested:
        if key not in on_disk:
            listing = "; ".join(
                f"{mission}: {', '.join(sorted(views)) or 'none'}"
                for mission, views in present.items()
            )
            raise DatasetNotFoundError(
                f"{what} {key!r} (no viewpoint folder of the selected missions)",
                root,
                f"Viewpoint folders present: {listing}. Select among those, or leave {what} "
                "at None for all present",
            )


def list_frames(
    root: str | Path,
    missions: Sequence[str] | str | None = None,
    altitude: Sequence[str] | str | None = None,
    direction: Sequence[str] | str | None = None,
    fields: Sequence[str] | str | None = None,
    *,
    skip_incomplete: bool = False,
) -> list[Frame]:
    """List the frames of a selection, checking that every requested file exists.

    Args:
        root: the ClaraVid root, holding the mission folders.
        missions: SDK mission keys (aliases and folder names are accepted); None: all
            missions present under ``root``.
        altitude: ``low``, ``mid``, ``high``; None: all present.
        direction: ``h``, ``v``; None: all present.
        fields: SDK field keys; None: all fields. Frames are the stems found in any of the
            requested modality folders (the listing is symmetric).
        skip_incomplete: leave out, with one warning counting them, frames that miss a file
            in one of the requested modalities; by default such a frame is an error naming
            the missing file.

    Raises:
        DatasetNotFoundError: the root, a requested mission or modality folder does not
            exist, an explicitly named altitude or direction matches no viewpoint folder,
            or the selection holds no frame; the message names what exists.
        FileNotFoundError: a frame misses one modality (unless ``skip_incomplete``).
        ValueError: an unknown mission, altitude, direction or field key.
    """
    root = Path(root).expanduser()
    if not root.is_dir():
        raise DatasetNotFoundError("ClaraVid root", root, _GET_DATA)
    if isinstance(missions, str):
        missions = [missions]
    if missions is not None:
        chosen = list(dict.fromkeys(canonical_mission(m) for m in missions))
        if not chosen:
            raise ValueError(f"no mission selected; pass None for all, or some of {list(MISSIONS)}")
    else:
        chosen = [m for m in MISSIONS if (root / MISSIONS[m]).is_dir()]
        if not chosen:
            raise DatasetNotFoundError("ClaraVid mission folders", root, _GET_DATA)
    altitudes = choose_keys(altitude, ALTITUDES, "altitude")
    directions = choose_keys(direction, DIRECTIONS, "direction")
    field_keys = choose_keys(fields, MODALITIES, "field")
    file_fields = [f for f in field_keys if MODALITIES[f].folder is not None]
    if not file_fields:
        raise ValueError(f"fields {field_keys} have no files to list frames by; add e.g. 'rgb'")

    present: dict[str, set[str]] = {}
    for mission in chosen:
        mission_dir = root / MISSIONS[mission]
        if not mission_dir.is_dir():
            raise DatasetNotFoundError(f"mission {mission!r}", mission_dir, _GET_DATA)
        for key in file_fields:
            modality_dir = MODALITIES[key].folder_in(mission_dir)
            if not modality_dir.is_dir():
                raise DatasetNotFoundError(f"modality {key!r} of mission {mission!r}", modality_dir)
        present[mission] = _viewpoints(mission_dir, file_fields)
    _check_explicit(altitude, 0, "altitude", present, root)
    _check_explicit(direction, 1, "direction", present, root)

    frames: list[Frame] = []
    missing: list[Path] = []
    incomplete = 0
    for mission in chosen:
        mission_dir = root / MISSIONS[mission]
        for alt in altitudes:
            for drc in directions:
                view = viewpoint_folder(alt, drc)
                if view not in present[mission]:
                    continue
                # Stems of each modality; a viewpoint folder absent in one modality is empty.
                stems = {}
                for key in file_fields:
                    modality = MODALITIES[key]
                    folder = modality.folder_in(mission_dir) / view
                    stems[key] = _stems(folder, f".{modality.ext}") if folder.is_dir() else set()
                for stem in sorted(set().union(*stems.values())):
                    paths = {key: frame_file(mission_dir, view, stem, key) for key in file_fields}
                    absent = [paths[k] for k in file_fields if stem not in stems[k]]
                    if absent:
                        missing.extend(absent)
                        incomplete += 1
                        continue
                    frames.append(Frame(mission, alt, drc, stem, paths))
    if missing:
        listing = "\n  ".join(str(p) for p in missing[:10])
        more = f"\n  … and {len(missing) - 10} more" if len(missing) > 10 else ""
        if not skip_incomplete:
            raise FileNotFoundError(
                f"{incomplete} frame(s) miss {len(missing)} file(s) of the requested fields "
                f"{file_fields}:\n  {listing}{more}\nRestore them, request fewer fields, or "
                "pass skip_incomplete=True to leave those frames out."
            )
        warnings.warn(
            f"left out {incomplete} incomplete frame(s) missing {len(missing)} file(s), "
            f"e.g. {missing[0]}",
            stacklevel=2,
        )
    if not frames:
        raise DatasetNotFoundError(
            f"frames of fields {file_fields} for missions {chosen}, altitude {altitudes}, "
            f"direction {directions}",
            MODALITIES[file_fields[0]].folder_in(root / MISSIONS[chosen[0]]),
            "Check the selection against the viewpoint folders present",
        )
    return frames

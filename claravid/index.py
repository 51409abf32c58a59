"""Listing ClaraVid frames: which files make up each frame of a selection.

A frame is one ``<stem>`` present in every requested modality folder of one viewpoint.
Frames are listed as the official SDK lists them: mission by mission (in the requested
order), then altitude, then direction, then sorted file name, anchored on the first
requested field that has files.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from claravid.errors import DatasetNotFoundError
from claravid.layout import (
    ALTITUDES,
    DIRECTIONS,
    MISSIONS,
    MODALITIES,
    canonical_mission,
    frame_file,
    viewpoint_folder,
)

_GET_DATA = "Download ClaraVid and pass the folder that holds the mission folders (001_rural_1 …)"


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


def _choose(requested: Sequence[str] | str | None, valid: dict[str, str], what: str) -> list[str]:
    if requested is None:
        return list(valid)
    if isinstance(requested, str):
        requested = [requested]
    unknown = [r for r in requested if r not in valid]
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; valid: {', '.join(valid)}")
    return list(requested)


def _stems(folder: Path, ext: str) -> list[str]:
    suffix = f".{ext}"
    with os.scandir(folder) as entries:
        return sorted(e.name[: -len(suffix)] for e in entries if e.name.endswith(suffix))


def list_frames(
    root: str | Path,
    missions: Sequence[str] | None = None,
    altitude: Sequence[str] | str | None = None,
    direction: Sequence[str] | str | None = None,
    fields: Sequence[str] | None = None,
    *,
    skip_incomplete: bool = False,
) -> list[Frame]:
    """List the frames of a selection, checking that every requested file exists.

    Args:
        root: the ClaraVid root, holding the mission folders.
        missions: SDK mission keys (aliases and folder names are accepted); None: all
            missions present under ``root``.
        altitude: ``low``, ``mid``, ``high`` (None: all present).
        direction: ``h``, ``v`` (None: all present).
        fields: SDK field keys; None: all fields. The first field with files anchors the
            listing.
        skip_incomplete: leave out, with a warning, frames that miss a file in another
            modality; by default such a frame is an error naming the file.

    Raises:
        DatasetNotFoundError: the root, or a requested mission, modality or viewpoint folder,
            does not exist; the message names the path searched and what is there.
        FileNotFoundError: a frame misses one modality (unless ``skip_incomplete``).
        ValueError: an unknown mission, altitude, direction or field key.
    """
    root = Path(root).expanduser()
    if not root.is_dir():
        raise DatasetNotFoundError("ClaraVid root", root, _GET_DATA)
    if isinstance(missions, str):
        missions = [missions]
    chosen = [canonical_mission(m) for m in missions] if missions is not None else list(MISSIONS)
    if missions is None:
        chosen = [m for m in chosen if (root / MISSIONS[m]).is_dir()]
        if not chosen:
            raise DatasetNotFoundError("ClaraVid mission folders", root, _GET_DATA)
    altitudes = _choose(altitude, ALTITUDES, "altitude")
    directions = _choose(direction, DIRECTIONS, "direction")
    field_keys = _choose(fields, {k: k for k in MODALITIES}, "field")
    file_fields = [f for f in field_keys if MODALITIES[f].folder is not None]
    if not file_fields:
        raise ValueError(f"fields {field_keys} have no files to list frames by; add e.g. 'rgb'")
    explicit_viewpoints = altitude is not None or direction is not None

    frames: list[Frame] = []
    missing: list[Path] = []
    for mission in chosen:
        mission_dir = root / MISSIONS[mission]
        if not mission_dir.is_dir():
            raise DatasetNotFoundError(f"mission {mission!r}", mission_dir, _GET_DATA)
        for key in file_fields:
            modality_dir = mission_dir / MODALITIES[key].folder
            if not modality_dir.is_dir():
                raise DatasetNotFoundError(f"modality {key!r} of mission {mission!r}", modality_dir)
        anchor = MODALITIES[file_fields[0]]
        found_viewpoint = False
        for alt in altitudes:
            for drc in directions:
                view = viewpoint_folder(alt, drc)
                anchor_dir = mission_dir / anchor.folder / view
                if not anchor_dir.is_dir():
                    if explicit_viewpoints:
                        raise DatasetNotFoundError(f"viewpoint {view!r}", anchor_dir)
                    continue
                found_viewpoint = True
                stems = _stems(anchor_dir, anchor.ext)
                present = {
                    key: set(_stems(d, MODALITIES[key].ext)) if d.is_dir() else set()
                    for key in file_fields[1:]
                    for d in [mission_dir / MODALITIES[key].folder / view]
                }
                for stem in stems:
                    paths = {key: frame_file(mission_dir, view, stem, key) for key in file_fields}
                    absent = [paths[k] for k in file_fields[1:] if stem not in present[k]]
                    if absent:
                        missing.extend(absent)
                        continue
                    frames.append(Frame(mission, alt, drc, stem, paths))
        if not found_viewpoint:
            raise DatasetNotFoundError(
                f"viewpoint folders of mission {mission!r}", mission_dir / anchor.folder
            )
    if missing:
        listing = "\n  ".join(str(p) for p in missing[:10])
        more = f"\n  … and {len(missing) - 10} more" if len(missing) > 10 else ""
        if not skip_incomplete:
            raise FileNotFoundError(
                f"{len(missing)} file(s) of listed frames are missing:\n  {listing}{more}\n"
                "Restore them, or pass skip_incomplete=True to leave those frames out."
            )
        warnings.warn(
            f"left out {len(missing)} incomplete frame file(s), e.g. {missing[0]}", stacklevel=2
        )
    return frames

"""A folder of DJI photos to ``harborsight.frame/1`` files, one per photo, for ``measure``
and ``run``: what ``harborsight telemetry photos`` does.

Each frame is written as ``OUT/<photo stem>.json`` with ``image`` the photo's path relative to
``OUT`` (so ``harborsight measure OUT`` finds the photo where it is, without copying it). A
photo that cannot be a frame (no position, no capture time, the vessel track does not reach
its time, an image cut short, ...) is listed with its reason and the others are written.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from harborsight.errors import HarborsightError, InputError
from harborsight.files import natural_key, strict_json
from harborsight.geometry.sensor_sigmas import MAX_DEAD_RECKONED_S
from harborsight.telemetry.dji_photo import PHOTO_SUFFIXES, photo_frame, read_dji_photo
from harborsight.telemetry.track import Track


@dataclass
class PhotoBatch:
    written: list[tuple[Path, Path]] = field(default_factory=list)    # (photo, frame file)
    skipped: list[tuple[Path, str]] = field(default_factory=list)     # (photo, reason)
    notes: dict[str, list[str]] = field(default_factory=dict)         # note -> photo names
    #: frames written whose vessel pose is dead-reckoned past what is measured with
    #: (:data:`~harborsight.geometry.sensor_sigmas.MAX_DEAD_RECKONED_S`): `run` measures them
    #: where the frames before placed the vessel in the image, `measure` does not
    beyond_dead_reckoning: int = 0


def find_photos(inputs: Iterable[Path]) -> list[Path]:
    """The photos named, and those in the folders named (``.jpg``/``.jpeg`` in any letter
    case, not recursive), in natural order within each folder; :class:`InputError` for an
    input that does not exist or a folder without photos."""
    photos: list[Path] = []
    for item in inputs:
        item = Path(item)
        if item.is_dir():
            found = sorted((p for p in item.iterdir()
                            if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES),
                           key=lambda p: natural_key(p.name))
            if not found:
                raise InputError(item, None, "no .jpg/.jpeg photos in this folder")
            photos += found
        elif item.is_file():
            photos.append(item)
        else:
            raise InputError(item, None, "no such file or folder")
    return list(dict.fromkeys(photos))


def image_reference(photo: Path, out_dir: Path) -> str:
    """The photo's path as a frame file in ``out_dir`` names it: relative where it can be
    (POSIX separators), else absolute."""
    try:
        return Path(os.path.relpath(photo.resolve(), out_dir.resolve())).as_posix()
    except ValueError:                      # another drive (Windows)
        return photo.resolve().as_posix()


def write_photo_frames(
    photos: list[Path], vessel: Track, out_dir: Path, *, water_level_m: float,
    utc_offset_h: float | None = None, altitude: str = "relative", yaw_reference: str = "true",
    vessel_offset_s: float = 0.0, max_gap_s: float = 1.0, camera: dict | None = None,
    on_photo: Callable[[Path], None] | None = None,
) -> PhotoBatch:
    """Write a frame file per photo into ``out_dir`` (module docstring); each photo's notes
    are gathered by text in ``notes``."""
    batch = PhotoBatch()
    stems: set[str] = set()
    for index, photo_path in enumerate(photos):
        try:
            stem = photo_path.stem
            if stem in stems:
                raise InputError(photo_path, None, f"another photo named {stem} was written "
                                 "already (frames are named by the photo's stem)")
            photo = read_dji_photo(photo_path)
            result = photo_frame(
                photo, vessel, image=image_reference(photo_path, out_dir),
                water_level_m=water_level_m, utc_offset_h=utc_offset_h, altitude=altitude,
                yaw_reference=yaw_reference, vessel_offset_s=vessel_offset_s,
                max_gap_s=max_gap_s, camera=camera, index=index)
            for note in result.notes:
                batch.notes.setdefault(note, []).append(photo_path.name)
            if result.frame is None:
                batch.skipped.append((photo_path, result.reason or "left out"))
            else:
                target = out_dir / f"{stem}.json"
                target.write_text(strict_json(result.frame, indent=1) + "\n")
                stems.add(stem)
                batch.written.append((photo_path, target))
                reckoned_s = result.frame["vessel"].get("dead_reckoned_s") or 0.0
                batch.beyond_dead_reckoning += reckoned_s > MAX_DEAD_RECKONED_S
        except HarborsightError as exc:
            batch.skipped.append((photo_path, str(exc)))
        if on_photo is not None:
            on_photo(photo_path)
    return batch

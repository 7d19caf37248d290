"""Writing files so that a reader never sees half of one, JSON that strict parsers read,
and the natural order of file names."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through ``<name>.part``: flushed to disk, then renamed over
    ``path``. An interrupted write (power loss, full disk, Ctrl-C) leaves the old file or
    none, never a truncated one; a failed write removes its ``.part``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    try:
        with tmp.open("wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> None:
    """:func:`write_bytes_atomic` of UTF-8 text."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_image(path: str | Path, image) -> bool:
    """``cv2.imwrite`` that says whether the picture was written: False for a folder that
    cannot be written and for a name OpenCV has no encoder for (where it raises)."""
    import cv2

    try:
        return bool(cv2.imwrite(str(path), image))
    except cv2.error:
        return False


def is_existing_file(path: str | Path) -> bool:
    """``Path.is_file()`` that says False, not raises, for a name the file system cannot
    even look up (longer than its 255 bytes, a NUL byte): names read from users' files."""
    try:
        return Path(path).is_file()
    except (OSError, ValueError):
        return False


def finite_or_none(value):
    """``value`` with every non-finite float (NaN, ±inf), however deeply nested in dicts,
    lists and tuples, replaced by None: JSON has no NaN, and ``json.dumps`` would write a
    bare ``NaN`` that strict parsers reject."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite_or_none(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [finite_or_none(item) for item in value]
    if hasattr(value, "dtype") and hasattr(value, "tolist"):  # numpy scalars and arrays
        return finite_or_none(value.tolist())
    return value


def strict_json(value, **dumps_options) -> str:
    """``json.dumps`` of :func:`finite_or_none` (``value``), refusing anything else that is
    not strict JSON."""
    return json.dumps(finite_or_none(value), allow_nan=False, **dumps_options)


def natural_key(name: str) -> list:
    """Sort key for file names that orders runs of digits by value: ``frame_2`` before
    ``frame_10`` (letter case ignored, then the name itself breaks ties)."""
    parts = re.split(r"(\d+)", name)
    return [int(p) if i % 2 else p.casefold() for i, p in enumerate(parts)] + [name]


def _write_problem(path: Path) -> str | None:
    """Why nothing can be written at ``path`` (None: it looks writable), without creating it."""
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            return "no such place"
        probe = probe.parent
    if probe != path and not probe.is_dir():
        return f"{probe} is a file, not a folder"
    folder = probe if probe.is_dir() else probe.parent
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"{folder} cannot be written"
    return None


def prepare_output_folder(path: str | Path, option: str = "--out",
                          inputs: tuple[str | Path | None, ...] = ()) -> Path:
    """Create the output folder ``path`` (with its parents) or raise :class:`InputError`
    naming ``option``: when it is a file, cannot be created or written, or is the folder of
    one of ``inputs`` (files or folders read by the same command), whose files its outputs
    would overwrite or be read back as input on the next run."""
    from harborsight.errors import InputError

    path = check_output_folder(path, option, inputs)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(path, option, f"cannot create the output folder: "
                         f"{exc.strerror or exc}") from None
    return path


def check_output_folder(path: str | Path, option: str = "--out",
                        inputs: tuple[str | Path | None, ...] = ()) -> Path:
    """:func:`prepare_output_folder`'s checks without creating anything (for a command that
    writes nothing when it has nothing to write)."""
    from harborsight.errors import InputError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(path, option, "exists and is not a folder")
    resolved = path.resolve()
    for given in inputs:
        if given is None:
            continue
        given = Path(given).resolve()
        folder = given if given.is_dir() else given.parent
        if resolved == folder:
            raise InputError(path, option, f"is the folder of the input {given}: the outputs "
                             "would overwrite the inputs or be read as inputs next time; "
                             "give another folder")
    problem = _write_problem(path)
    if problem:
        raise InputError(path, option, f"cannot create the output folder: {problem}")
    return path


def prepare_output_file(path: str | Path, option: str = "--out") -> Path:
    """Create the parent folders of the output file ``path`` or raise :class:`InputError`
    naming ``option``: when ``path`` is a folder, or its folder cannot be created or
    written. Call it before the work, so that an hour of work is not lost to a bad name."""
    from harborsight.errors import InputError

    path = Path(path)
    if path.is_dir():
        raise InputError(path, option, "is a folder; give a file name")
    problem = _write_problem(path)
    if problem:
        raise InputError(path, option, f"cannot be written: {problem}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(path, option, f"cannot be written: {exc.strerror or exc}") from None
    return path

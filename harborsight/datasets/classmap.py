"""Class names of annotation tools -> harborsight classes (``--map boat=ship``).

An annotation names its class in its own words (``boat``, ``Dock``, ``boat lift``). Each name
is looked up case-insensitively (surrounding blanks dropped): first in the ``--map`` table,
then among harborsight's own names ``water`` (0), ``ship`` (1), ``obstacle`` (2) and
``ignore`` (255), so a tool whose classes already are these needs no table.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path

from harborsight.errors import InputError
from harborsight.perception.classes import IGNORE, OBSTACLE, SHIP, WATER
from harborsight.text_formats import load_yaml_text

#: harborsight's classes by name (what a --map target or an annotation may call them)
TARGETS = {"water": WATER, "ship": SHIP, "obstacle": OBSTACLE, "ignore": IGNORE}
#: ... and by value, for messages and dataset.json
TARGET_NAMES = {value: name for name, value in TARGETS.items()}


def normalise_name(name: str) -> str:
    """The lookup key of a class name: lower case, outer blanks dropped."""
    return str(name).strip().lower()


def parse_class_map(items: Iterable[str]) -> dict[str, int]:
    """``["boat=ship", "Dock=obstacle", "wake=0", "blur=255"]`` -> ``{"boat": 1, "dock": 2, ...}``.

    The target is a harborsight class name (water, ship, obstacle, ignore) or its number
    (0, 1, 2, 255). The source name is everything before the last ``=``, so a name may hold
    blanks (``"boat lift=obstacle"``). Raises :class:`InputError` (field ``--map``) for an
    item without ``=``, an empty name, an unknown target, or one name mapped to two classes.
    """
    mapping: dict[str, int] = {}
    for item in items:
        name, sep, target = str(item).rpartition("=")
        key, target = normalise_name(name), target.strip().lower()
        if not sep or not key:
            raise InputError(None, "--map", f"expected NAME=CLASS (e.g. boat=ship), got {item!r}")
        if target in TARGETS:
            value = TARGETS[target]
        elif target.isdigit() and int(target) in TARGET_NAMES:
            value = int(target)
        else:
            raise InputError(None, "--map", f"{item!r}: unknown class {target!r}; use water, ship, "
                             "obstacle, ignore or 0, 1, 2, 255")
        if mapping.get(key, value) != value:
            raise InputError(None, "--map", f"{name.strip()!r} is mapped to both "
                             f"{TARGET_NAMES[mapping[key]]} and {TARGET_NAMES[value]}")
        mapping[key] = value
    return mapping


def class_of(label: str, mapping: dict[str, int]) -> int | None:
    """The harborsight class of an annotation's class name, or None when it has none."""
    key = normalise_name(label)
    if key in mapping:
        return mapping[key]
    return TARGETS.get(key)


def read_class_names(path: str | Path) -> list[str]:
    """Class names in class-id order from a YOLO ``data.yaml``/``classes.yaml`` (``names:`` as a
    list, or a map ``{0: boat, 1: car}`` covering 0..n-1) or a ``classes.txt`` (one name a
    line; blank lines at the end ignored). Raises :class:`InputError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "class names file not found")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, None, f"cannot read: {exc}") from None
    if path.suffix.lower() in (".yaml", ".yml"):
        doc = load_yaml_text(text, path)
        names = doc.get("names") if isinstance(doc, dict) else None
        if isinstance(names, dict):
            try:
                by_id = {int(k): str(v) for k, v in names.items()}
            except (TypeError, ValueError):
                raise InputError(path, "names", "expected class ids as keys (0: boat)") from None
            if sorted(by_id) != list(range(len(by_id))):
                raise InputError(path, "names", f"class ids {sorted(by_id)} do not run 0..{len(by_id) - 1}")
            names = [by_id[i] for i in range(len(by_id))]
        if not isinstance(names, list) or not names:
            raise InputError(path, "names", "expected a non-empty list (or id -> name map) of class names")
        result = [str(n).strip() for n in names]
    else:
        lines = text.splitlines()
        while lines and not lines[-1].strip():
            lines.pop()
        result = [line.strip() for line in lines]
    if not result:
        raise InputError(path, "names", "no class names")
    empty = [i for i, name in enumerate(result) if not name]
    if empty:
        raise InputError(path, "names", f"class id {empty[0]} has an empty name")
    return result


def find_class_names_file(*folders: Path) -> Path | None:
    """The first ``data.yaml``, ``dataset.yaml``, ``classes.yaml`` or ``classes.txt`` in the
    folders, in that order of folders, then of names."""
    for folder in folders:
        for name in ("data.yaml", "dataset.yaml", "classes.yaml", "classes.txt"):
            if (folder / name).is_file():
                return folder / name
    return None


def read_split_file(path: str | Path) -> dict[str, str]:
    """``stem -> split`` from a CSV with the columns ``stem,split`` (a header row of those
    two words is skipped). Raises :class:`InputError` naming the file and line."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "split file not found")
    splits: dict[str, str] = {}
    with path.open(newline="", encoding="utf-8-sig") as handle:
        for number, row in enumerate(csv.reader(handle), 1):
            cells = [cell.strip() for cell in row]
            if not any(cells):
                continue
            if number == 1 and [c.lower() for c in cells[:2]] == ["stem", "split"]:
                continue
            if len(cells) < 2 or not cells[0] or not cells[1]:
                raise InputError(path, f"line {number}", f"expected stem,split, got {','.join(row)!r}")
            stem, split = cells[0], cells[1]
            if splits.get(stem, split) != split:
                raise InputError(path, f"line {number}", f"{stem!r} is in both {splits[stem]!r} "
                                 f"and {split!r}")
            splits[stem] = split
    if not splits:
        raise InputError(path, None, "no rows (expected stem,split lines)")
    return splits


def splits_of(stems: list[str], split: str | None, split_file: str | Path | None,
              what: str = "image") -> dict[str, str]:
    """Each stem's split: ``split`` (default train) for all, or the ``split_file`` CSV
    (:func:`read_split_file`), which must list every stem (``what`` names them in the error)."""
    if split is not None and split_file is not None:
        raise InputError(None, "--split", "give --split or --split-file, not both")
    if split_file is None:
        return dict.fromkeys(stems, split or "train")
    listed = read_split_file(split_file)
    missing = [stem for stem in stems if stem not in listed]
    if missing:
        raise InputError(split_file, "stem", f"{len(missing)} {what}(s) not listed: "
                         + ", ".join(missing[:10]) + (" ..." if len(missing) > 10 else ""))
    return {stem: listed[stem] for stem in stems}


def unknown_labels_error(source: str, unknown: dict[str, int], first_file: dict[str, str]
                         ) -> InputError:
    """The error for class names that have no harborsight class: every such name with its
    count of shapes and the first file it is in. ``source`` names the input as a whole; when
    all the names come from one file, that file is named instead."""
    files = {first_file[name] for name in unknown}
    source = files.pop() if len(files) == 1 else source
    listed = ", ".join(f"{name!r} ({n} shape{'s' if n != 1 else ''}, first in {first_file[name]})"
                       for name, n in sorted(unknown.items(), key=lambda kv: kv[0].lower()))
    return InputError(source, "label", f"{len(unknown)} class name(s) with no harborsight class: "
                      f"{listed}; map each with --map NAME=water|ship|obstacle|ignore")

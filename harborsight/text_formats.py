"""JSON and YAML text read with every way it can fail an :class:`InputError` naming the file
and, where it can be told, the field: bad syntax, nesting too deep for Python's readers (a
RecursionError), and whole numbers of more than 4300 digits (which Python refuses to read).
Light on purpose (no geodesy, meshes or camera maths): the training and dataset readers use it
on machines that have only the training stack."""

from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

from harborsight.errors import InputError, brief


def parse_json_text(text: str, source: str | Path | None) -> object:
    """``json.loads(text)``, with every way text can fail to be JSON an :class:`InputError`
    on ``source``: bad syntax, a whole number of more than 4300 digits (Python refuses to
    read it; named by its key and place, also inside a list), or arrays/objects nested too
    deep to read (a RecursionError)."""
    too_long: list[_LongWhole] = []

    def whole(digits: str) -> int | _LongWhole:
        try:
            return int(digits)
        except ValueError:              # int("1" * 5000): Python's limit on digits
            too_long.append(_LongWhole(digits))
            return too_long[-1]

    try:
        value = json.loads(text, parse_int=whole)
    except json.JSONDecodeError as exc:
        raise InputError(source, None, f"not valid JSON: {exc}") from None
    except RecursionError:
        raise InputError(source, None, "not valid JSON: arrays or objects nested too deep "
                         "to read") from None
    if too_long:
        key, place = _place_of(value, too_long[0])
        digits = len(too_long[0].lstrip("-"))
        what = f"{brief(key)} holds" if key is not None else f"{place or 'the value'} is"
        where = f"at {place}; " if place and key is not None and place != key else ""
        raise InputError(source, None, f"not valid JSON: {what} a whole number of {digits} "
                         f"digits ({where}too long to read: at most 4300)")
    return value


class _LongWhole(str):
    """The digits of a JSON whole number too long for Python to read (a marker that
    :func:`parse_json_text` looks for)."""


def _place_of(value: object, target: object) -> tuple[str | None, str]:
    """Where ``target`` (compared by identity) sits in ``value``: the innermost key above
    it and its dotted path with list positions, e.g. ``('distortion',
    'camera.distortion[0]')``. Walked without recursion: ``value`` may be deep."""
    stack: list[tuple[object, str | None, str]] = [(value, None, "")]
    while stack:
        node, key, place = stack.pop()
        if node is target:
            return key, place
        if isinstance(node, dict):
            stack.extend((item, str(name), f"{place}.{name}" if place else str(name))
                         for name, item in node.items())
        elif isinstance(node, list):
            stack.extend((item, key, f"{place}[{i}]") for i, item in enumerate(node))
    return None, ""


_KEY_ON_LINE = re.compile(r"^\s*(?:-\s*)?(?:<(\w+)|([A-Za-z_]\w*)\s*:)")


def long_whole_number(text: str, min_digits: int) -> tuple[str, int, str] | None:
    """The first whole number of ``min_digits`` digits or more in YAML or XML text, as
    ``(field, line number, its digits cut short)``: the field is the key on its line, under
    the last top-level key for a nested line, or ``line N`` where no key is known."""
    pattern = re.compile(rf"(?<![\w.+-])[-+]?\d{{{min_digits},}}(?![\w.])")
    top = None
    for number, line in enumerate(text.splitlines(), start=1):
        key = _KEY_ON_LINE.match(line)
        name = (key.group(1) or key.group(2)) if key else None
        nested = line[:1].isspace() or line.startswith("-")
        if name and not nested:
            top = name
        if (m := pattern.search(line)) is not None:
            field = name or f"line {number}"
            if nested and top:
                field = f"{top}.{name}" if name else top
            digits = m.group().lstrip("+-")
            shown = digits if len(digits) <= 20 else f"{digits[:12]}... ({len(digits)} digits)"
            return field, number, shown
    return None


def load_yaml_text(text: str, path: Path) -> object:
    """``yaml.safe_load(text)``, every way it fails an :class:`InputError` on ``path``: bad
    syntax, nesting too deep to read (a RecursionError), a whole number of more than 4300
    digits (Python refuses to read it; named by its key) or a bad value (the date 2024-13-01)."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(path, None, "not valid YAML: " + " ".join(str(exc).split())) from exc
    except RecursionError:
        raise InputError(path, None, "not valid YAML: nested too deep to read") from None
    except ValueError as exc:
        if "digits" in str(exc) and (found := long_whole_number(text, 4301)) is not None:
            field, line, shown = found
            raise InputError(path, field, f"{shown} on line {line}: a whole number of more than "
                             "4300 digits is too long to read") from None
        raise InputError(path, None, f"not valid YAML: {brief(str(exc), 80)}") from None

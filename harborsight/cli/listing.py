"""Long lists of per-frame messages, said once per kind: a flight of thousands of frames with
the same trouble (a vessel report too old, a damaged stretch of video) must not bury the rest
of the output. The terminal shows the first few of each kind in full, then how many more,
which frames, and the range of each quantity they hold; ``run.json`` keeps every message.

A message's kind is its text without its source (``path: ``) and with every *quantity* made
``#``: a number with a unit (``31 s``, ``2.5 m``, ``16 px``, ``40 %``) or with a decimal
point. Other numbers stay, for they name the problem rather than measure it: ``class 3`` and
``class 128``, ``[Errno 28]`` and ``[Errno 5]``, ``tug2.yaml`` and ``tug7.yaml`` are kinds of
their own.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

#: messages of one kind shown in full before the rest are counted
SHOWN_PER_KIND = 3
#: frame ranges named before the rest are elided (frame numbers; names are all given)
RANGES_SHOWN = 6
#: the units that make a number a quantity
UNITS = frozenset({"s", "ms", "m", "mm", "cm", "km", "m/s", "px", "%", "deg", "°", "x", "kn",
                   "Hz", "fps", "MiB", "KiB", "MB", "KB", "kB"})
_NUMBER = re.compile(r"(?<![\w.])([-+]?\d+(?:\.\d+)?)(\s?)([A-Za-z%°/]+)?")
_NAME = re.compile(r"^(.*?)(\d+)$")


def _quantities(message: str) -> tuple[str, list[tuple[float, str]]]:
    """``message`` with its quantities made ``#`` (their units kept), and the quantities."""
    found: list[tuple[float, str]] = []

    def replace(match: re.Match) -> str:
        number, space, word = match[1], match[2], match[3] or ""
        if word in UNITS:
            found.append((float(number), word))
        elif "." in number:
            found.append((float(number), ""))
        else:
            return match[0]
        return f"#{space}{word}"

    return _NUMBER.sub(replace, message), found


def message_kind(message: str, source: str | None = None) -> str:
    """``message`` without its ``source: `` prefix (and a file named after the source after
    it: ``000019: frames/000019.json: ...``), its quantities made ``#``."""
    if source and message.startswith(f"{source}: "):
        message = message[len(source) + 2:]
        head, colon, rest = message.partition(": ")
        if colon and source in head and " " not in head:
            message = rest
    return _quantities(message)[0]


def frame_ranges(frames: Iterable[int], shown: int = RANGES_SHOWN) -> str:
    """Sorted frame numbers as ranges: ``4-9, 12, 15-47`` (the first ``shown``, then ``...``)."""
    ordered = sorted(set(frames))
    ranges: list[tuple[int, int]] = []
    for frame in ordered:
        if ranges and frame == ranges[-1][1] + 1:
            ranges[-1] = (ranges[-1][0], frame)
        else:
            ranges.append((frame, frame))
    text = [f"{a}" if a == b else f"{a}-{b}" for a, b in ranges[:shown]]
    return ", ".join(text) + (", ..." if len(ranges) > shown else "")


def name_ranges(names: Iterable[str]) -> str:
    """Names, every one, runs of consecutive numbered names made ranges:
    ``DJI_0007-0012, DJI_0020, harbor3``."""
    runs: list[list] = []          # [prefix, width, first, last] or [name]
    for name in names:
        match = _NAME.match(name)
        if match:
            prefix, digits = match[1], match[2]
            last = runs[-1] if runs else None
            if (last is not None and len(last) == 4 and last[0] == prefix
                    and last[1] == len(digits) and int(digits) == last[3] + 1):
                last[3] = int(digits)
                continue
            runs.append([prefix, len(digits), int(digits), int(digits)])
        else:
            runs.append([name])
    text = []
    for run in runs:
        if len(run) == 1:
            text.append(run[0])
        else:
            prefix, width, first, last = run
            text.append(f"{prefix}{first:0{width}d}" + (f"-{last:0{width}d}" if last != first else ""))
    return ", ".join(text)


def _spans(members: list[str]) -> str:
    """The range of each quantity over ``members`` (one kind: the same quantities in order)."""
    columns = [_quantities(message)[1] for message in members]
    spans = []
    for slot in range(min(len(column) for column in columns)):
        values = [column[slot][0] for column in columns]
        unit = columns[0][slot][1]
        low, high = min(values), max(values)
        spans.append((f"{low:g}" if low == high else f"{low:g} to {high:g}") + (f" {unit}" if unit else ""))
    return ", ".join(spans)


def grouped_lines(items: Iterable[tuple[int | str | None, str, str | None]],
                  shown: int = SHOWN_PER_KIND) -> list[str]:
    """Indented lines for ``(frame, message, source)`` items (``frame`` a number, a name, or
    None): each kind's first ``shown`` messages in full, then one line counting the rest,
    naming their frames and the range of each quantity; kinds in the order they first came."""
    groups: dict[str, list[tuple[int | str | None, str]]] = {}
    for frame, message, source in items:
        groups.setdefault(message_kind(message, source), []).append((frame, message))
    lines = []
    for members in groups.values():
        lines += [f"  {message}" for _, message in members[:shown]]
        rest = members[shown:]
        if not rest:
            continue
        numbers = [frame for frame, _ in rest if isinstance(frame, int)]
        names = [frame for frame, _ in rest if isinstance(frame, str)]
        about = [f"frames {frame_ranges(numbers)}"] if numbers else []
        about += [name_ranges(names)] if names else []
        spans = _spans([message for _, message in rest])
        about += [spans] if spans else []
        where = f" ({'; '.join(about)})" if about else ""
        lines.append(f"  ... and {len(rest)} more like the last{where}")
    return lines

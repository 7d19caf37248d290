"""Long lists of per-frame messages, said once per kind: a flight of thousands of frames with
the same trouble (a vessel report too old, a damaged stretch of video) must not bury the rest
of the output. Every message stays in ``run.json``; the terminal shows the first few of each
kind and how many more, with their frames.

A message's kind is its text without its source (``path: ``) and with every number made
``#``: "the vessel's pose was carried 31 s ..." and "... carried 44 s ..." are one kind.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

#: messages of one kind shown in full before the rest are counted
SHOWN_PER_KIND = 3
#: frame ranges named before the rest are elided
RANGES_SHOWN = 6
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def message_kind(message: str, source: str | None = None) -> str:
    """``message`` without its ``source: `` prefix, every number replaced by ``#``."""
    if source and message.startswith(f"{source}: "):
        message = message[len(source) + 2:]
    return _NUMBER.sub("#", message)


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


def grouped_lines(items: Iterable[tuple[int | None, str, str | None]],
                  shown: int = SHOWN_PER_KIND) -> list[str]:
    """Indented lines for ``(frame, message, source)`` items: each kind's first ``shown``
    messages in full, then one line counting the rest and naming their frames; kinds in the
    order they first came."""
    groups: dict[str, list[tuple[int | None, str]]] = {}
    for frame, message, source in items:
        groups.setdefault(message_kind(message, source), []).append((frame, message))
    lines = []
    for members in groups.values():
        lines += [f"  {message}" for _, message in members[:shown]]
        rest = members[shown:]
        if rest:
            frames = [frame for frame, _ in rest if isinstance(frame, int)]
            where = f" (frames {frame_ranges(frames)})" if frames else ""
            lines.append(f"  ... and {len(rest)} more like the last{where}")
    return lines

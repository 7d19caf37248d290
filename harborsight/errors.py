"""Errors a user can act on: each names the file and the field at fault."""

from __future__ import annotations

import math
from pathlib import Path


class HarborsightError(Exception):
    """Base class of every error harborsight raises on purpose."""


class InputError(HarborsightError):
    """Bad input: ``<source>: <field>: <what is wrong>`` on one line."""

    def __init__(self, source: str | Path | None, field: str | None, message: str) -> None:
        self.source = str(source) if source is not None else None
        self.field = field
        self.message = message
        parts = [p for p in (self.source, field) if p]
        super().__init__(": ".join([*parts, message]))


def brief(value: object, limit: int = 40) -> str:
    """``repr(value)`` cut to about ``limit`` characters, for messages: a field may hold a
    number of 4000 digits or a long string, and an error must stay one readable line."""
    try:
        text = repr(value)
    except ValueError:                  # an int past Python's limit on the digits it prints
        return "a whole number of more than 4300 digits"
    if len(text) <= limit:
        return text
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{text[:12]}... (a whole number of {len(text.lstrip('-'))} digits)"
    return text[:limit - 3] + "..."


def require_positive(settings: object, names: tuple[str, ...]) -> None:
    """Raise ValueError naming the first of ``names`` on ``settings`` that is not a finite
    number above 0 (settings dataclasses check themselves with it)."""
    for name in names:
        value = getattr(settings, name)
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value}")

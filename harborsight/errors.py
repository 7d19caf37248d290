"""Errors a user can act on: each names the file and the field at fault."""

from __future__ import annotations

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

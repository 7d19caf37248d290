"""Every number given on the command line is finite.

Click's float options accept ``nan`` and ``inf`` (``FloatRange`` compares, and NaN fails no
comparison), and a NaN water level or camera pitch then flows into the geometry. Rather than
a check in each of some forty options, every command's callback is wrapped once
(:func:`refuse_non_finite_numbers`): a non-finite float in any argument (or in a list of
them) is a usage error naming the option, before the command runs.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import typer


def _non_finite(value) -> bool:
    if isinstance(value, float):
        return not math.isfinite(value)
    if isinstance(value, list | tuple):
        return any(_non_finite(item) for item in value)
    return False


def finite_numbers(callback: Callable) -> Callable:
    """``callback`` refusing non-finite float arguments with a ``typer.BadParameter``."""
    if getattr(callback, "_finite_numbers", False):
        return callback

    @functools.wraps(callback)
    def checked(*args, **kwargs):
        for name, value in kwargs.items():
            if _non_finite(value):
                option = "--" + name.rstrip("_").replace("_", "-")
                raise typer.BadParameter(f"must be a finite number, got {value!r}",
                                         param_hint=f"'{option}'")
        return callback(*args, **kwargs)

    checked._finite_numbers = True
    return checked


def refuse_non_finite_numbers(app: typer.Typer) -> None:
    """Wrap the callback of every command of ``app`` and of its command groups."""
    for info in app.registered_commands:
        if info.callback is not None:
            info.callback = finite_numbers(info.callback)
    for group in app.registered_groups:
        if group.typer_instance is not None:
            refuse_non_finite_numbers(group.typer_instance)

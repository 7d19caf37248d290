"""Usage lines that name arguments as Unix tools do: ``harborsight measure [OPTIONS]
INPUT``. Typer (0.29) writes a required argument in braces (``{INPUT}``) and repeats the
``...`` of a metavar that has its own (``{INPUT...}...``); :func:`use_plain_usage_names`
replaces that one method of its argument class (the CLI calls it once, whatever command
runs). Everything else of the help is Typer's."""

from __future__ import annotations

from typer.core import TyperArgument


def plain_usage_name(argument: TyperArgument) -> str:
    """``NAME`` for a required argument, ``[NAME]`` for an optional one, ``NAME...`` for
    one that takes several; in upper case."""
    name = argument.display_name_raw.upper()
    several = argument.nargs != 1 or name.endswith("...")
    name = name.removesuffix("...")
    if not argument.required:
        name = f"[{name}]"
    return f"{name}..." if several else name


def use_plain_usage_names() -> None:
    """Make every Typer argument's usage name :func:`plain_usage_name` (idempotent)."""
    TyperArgument._usage_display_name = plain_usage_name


"""Every command's --help (issue #30): arguments named in plain upper case (INPUT, not
{INPUT}), and every option's help, bracketed defaults such as [test] included, printed
whole (Rich markup once took "[test]" for a tag and printed nothing)."""

import re

import pytest
import typer
from typer.testing import CliRunner

from harborsight.cli import app

runner = CliRunner()


def _commands(command, path: tuple[str, ...] = ()):
    """(path, click command) of the app and every command and group under it."""
    yield path, command
    for name, sub in sorted(getattr(command, "commands", {}).items()):
        yield from _commands(sub, (*path, name))


COMMANDS = list(_commands(typer.main.get_command(app)))


def _words(text: str) -> str:
    """``text`` without any white space (the help wraps lines at spaces and hyphens)."""
    return "".join(text.split())


def test_every_command_is_checked():
    names = {" ".join(path) for path, _ in COMMANDS}
    assert {"measure", "run", "segment", "contact-sheet", "dataset import",
            "telemetry show", "telemetry video", "evaluate segmentation", "train"} <= names


@pytest.mark.parametrize("path, command", COMMANDS, ids=[" ".join(p) or "harborsight"
                                                          for p, _ in COMMANDS])
def test_help_names_arguments_plainly_and_prints_every_option_whole(path, command):
    result = runner.invoke(app, [*path, "--help"], terminal_width=100)
    assert result.exit_code == 0, result.output
    output = result.output
    assert "{" not in output and "}" not in output, output
    usage = " ".join(output.split("\n\n")[0].split())
    assert usage.startswith("Usage: "), output
    for param in command.params:
        if isinstance(param, typer.core.TyperArgument):
            shown = param.display_name_raw.upper().removesuffix("...")
            assert re.search(rf"(^|\s|\[){re.escape(shown)}(\.\.\.)?\]?(\s|$)", usage), usage
    ctx = command.make_context(command.name or "harborsight", [], resilient_parsing=True)
    text = _words(output)
    for param in command.params:
        record = param.get_help_record(ctx)
        if record is None:
            continue
        name, help_text = record
        assert _words(help_text) in text, (name, help_text)
        for bracketed in re.findall(r"\[[^\]]*\]", param.help or "") if hasattr(param, "help") else ():
            assert _words(bracketed) in text, (name, bracketed)

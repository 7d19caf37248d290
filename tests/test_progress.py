"""Progress of long commands on a terminal (a Rich bar) and elsewhere (CI logs, `| tee`): a
plain line every few seconds and one at the end (issue #30)."""

import io
import re
import shutil
import time
from importlib import resources
from pathlib import Path

from rich.console import Console
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.progress import plain_line, progress_report

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
runner = CliRunner()
LINE = re.compile(r"^run: (\d+)/5 frames, (\d+) %, 0:00:\d\d elapsed$", re.MULTILINE)


def _console(terminal: bool) -> tuple[Console, io.StringIO]:
    buffer = io.StringIO()
    return Console(file=buffer, force_terminal=terminal, width=100), buffer


def test_plain_line():
    assert plain_line("run", 120, 480, "frames", 70.4) == "run: 120/480 frames, 25 %, 0:01:10 elapsed"
    assert plain_line("segment", 3, None, "images", 3725, "2 skipped") == (
        "segment: 3 images, 1:02:05 elapsed, 2 skipped")


def test_a_resumed_task_shows_the_time_left_from_its_own_pace():
    console, buffer = _console(terminal=False)
    now = [100.0]
    with progress_report("training x", 100, console, unit="iterations", completed=40,
                         remaining=True, every_s=3600, clock=lambda: now[0]) as report:
        now[0] += 30.0
        report.advance(10, note="loss 0.5000")     # 10 in 30 s: the other 50 take 150 s
    assert buffer.getvalue().splitlines() == [
        "training x: 50/100 iterations, 50 %, 0:00:30 elapsed, 0:02:30 left, loss 0.5000"]
    assert plain_line("run", 3, 3, "frames", 9.0, remaining_s=0.0).endswith("elapsed, 0:00:00 left")


def test_a_non_terminal_gets_a_line_every_few_seconds_and_one_at_the_end():
    console, buffer = _console(terminal=False)
    with progress_report("run", 4, console, every_s=0.05) as report:
        report.advance()
        time.sleep(0.3)             # one slow item: the log still shows the run is alive
        report.advance(note="1 skipped")
    lines = buffer.getvalue().splitlines()
    assert len(lines) >= 4, lines
    assert all(line.startswith("run: ") and "\x1b" not in line for line in lines)
    assert "run: 1/4 frames, 25 %, 0:00:00 elapsed" in lines
    assert lines[-1] == "run: 2/4 frames, 50 %, 0:00:00 elapsed, 1 skipped"


def test_a_terminal_gets_the_bar_and_disabled_shows_nothing():
    console, buffer = _console(terminal=True)
    with progress_report("run", 2, console, transient=False) as report:
        report.advance()
        report.advance(note="1 skipped")
    shown = buffer.getvalue()
    assert "2/2" in shown and "1 skipped" in shown and "elapsed" not in shown
    console, buffer = _console(terminal=False)
    with progress_report("run", 2, console, enabled=False) as report:
        report.advance()
    assert buffer.getvalue() == "" and report.completed == 1


def test_run_prints_plain_progress_when_not_on_a_terminal(tmp_path):
    data = tmp_path / "samples"
    shutil.copytree(SAMPLES, data, ignore=shutil.ignore_patterns("flight"))
    result = runner.invoke(app, ["run", str(data), "--masks", str(data / "labels"), "--no-video",
                                 "--out", str(tmp_path / "out")], terminal_width=200)
    assert result.exit_code == 0, result.output
    found = LINE.findall(result.output)
    assert found and found[-1] == ("5", "100"), result.output
    assert "\x1b" not in result.output

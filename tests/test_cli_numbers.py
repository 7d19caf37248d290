"""Non-finite numbers on the command line are usage errors naming the option (issue #30:
--water-level-m nan, --camera-yaw-deg inf, --vessel-offset-s nan flowed into the geometry)."""

from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.cli.numbers import finite_numbers

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "harborsight" / "data" / "samples"
TELEMETRY = ROOT.parent / "shared" / "data" / "telemetry"
runner = CliRunner()


def telemetry_video(tmp_path, option: str, value: str) -> list[str]:
    track = tmp_path / "vessel.csv"
    track.write_text("time_s,lat,lon,heading_deg\n0,41.42,2.23,90\n10,41.42,2.23,90\n")
    return ["telemetry", "video", str(TELEMETRY / "dji" / "air2s.srt"), "--vessel-track", str(track),
            "--camera", "dji-air2s", "--water-level-m", "0", "--out", str(tmp_path / "f.jsonl"),
            "--frames", "5", "--fps", "30", option, value]


@pytest.mark.parametrize("option, value", [("--water-level-m", "nan"), ("--camera-yaw-deg", "inf"),
                                           ("--vessel-offset-s", "nan"), ("--utc-offset-h", "-inf")])
def test_telemetry_video_refuses_non_finite_numbers(tmp_path, option, value):
    args = telemetry_video(tmp_path, option, value)
    if option == "--water-level-m":
        args = args[:args.index("--water-level-m")] + args[args.index("--water-level-m") + 2:]
    result = runner.invoke(app, args, terminal_width=200)
    assert result.exit_code == 2, result.output
    # a bounded option is refused by its range check, the others by the finiteness guard
    assert (f"Invalid value for '{option}': must be a finite number" in result.output
            or f"Invalid value for '{option}': Input should be" in result.output)
    assert not (tmp_path / "f.jsonl").exists()


@pytest.mark.parametrize("args", [
    ["run", str(SAMPLES / "flight"), "--window-s", "inf"],
    ["train", "--model", "ddrnet23_slim", "--data", str(SAMPLES), "--lr", "nan"],
    ["evaluate", "segmentation", "--data", str(SAMPLES), "--model", "m.onnx", "--fps-seconds", "nan"],
])
def test_commands_and_groups_refuse_non_finite_numbers(tmp_path, args):
    result = runner.invoke(app, [*args, "--out" if args[0] != "evaluate" else "--json",
                                 str(tmp_path / "out")], terminal_width=200)
    assert result.exit_code == 2, result.output
    assert "must be a finite number" in result.output or "Input should be" in result.output
    assert not (tmp_path / "out").exists()


def test_the_guard_checks_lists_and_wraps_once():
    calls = []
    guarded = finite_numbers(lambda weights=(1.0,), name="x": calls.append(weights))
    guarded(weights=[1.0, 2.0])
    assert calls == [[1.0, 2.0]]
    with pytest.raises(typer.BadParameter, match="finite") as caught:
        guarded(weights=[1.0, float("nan")])
    assert caught.value.param_hint == "'--weights'"
    assert finite_numbers(guarded) is guarded


def test_help_shows_bracketed_defaults():
    """Rich markup took "[test]" for a tag and printed nothing (issue #30)."""
    result = runner.invoke(app, ["evaluate", "segmentation", "--help"], terminal_width=200)
    assert "one table row each [test]" in result.output
    result = runner.invoke(app, ["train", "--help"], terminal_width=200)
    assert "Split to train on [train]" in result.output and "cuda[:N] [auto]" in result.output


@pytest.mark.parametrize("option, value, bound", [
    ("--camera-pitch-deg", "90", "less than or equal to 0"),
    ("--camera-pitch-deg", "-120", "greater than or equal to -90"),
    ("--utc-offset-h", "1e12", "less than or equal to 14"),
    ("--fps", "1e9", "less than or equal to 1000"),
    ("--frames", "2000000000", "less than or equal to 10000000"),
    ("--vessel-offset-s", "1e9", "less than or equal to 86400"),
    ("--water-level-m", "-5000", "greater than or equal to -1000"),
])
def test_telemetry_video_refuses_numbers_out_of_range(tmp_path, option, value, bound):
    """Finite but absurd: a camera looking up, a time zone 10^12 hours away, a video of two
    billion frames (issue #30)."""
    args = telemetry_video(tmp_path, option, value)
    for repeated in ("--water-level-m", "--fps", "--frames"):
        if option == repeated:
            k = args.index(repeated)
            args = args[:k] + args[k + 2:]
    result = runner.invoke(app, args, terminal_width=200)
    assert result.exit_code == 2, result.output
    assert f"Invalid value for '{option}'" in result.output and bound in result.output
    assert not (tmp_path / "f.jsonl").exists()

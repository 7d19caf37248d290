"""Bad output places and out-of-range options: one line naming the option, exit 2, before
any work is done, and never an input overwritten (issue #30)."""

import shutil
from importlib import resources
from pathlib import Path

import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.files import prepare_output_file, prepare_output_folder

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
LOGS = SAMPLES / "flight" / "logs"
runner = CliRunner()


@pytest.fixture
def dataset(tmp_path) -> Path:
    target = tmp_path / "samples"
    shutil.copytree(SAMPLES, target, ignore=shutil.ignore_patterns("flight"))
    return target


def _measure(dataset: Path, *extra: str) -> list[str]:
    return ["measure", str(dataset / "images" / "000000.png"), "--meta",
            str(dataset / "frames" / "000000.json"), "--mask", str(dataset / "labels" / "000000.png"),
            "--no-tables", *extra]


def _one_error_line(result, *words: str) -> None:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, result.output
    for word in words:
        assert word in errors[0], errors[0]


def test_output_folder_checks(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(InputError, match="--out: exists and is not a folder"):
        prepare_output_folder(a_file)
    with pytest.raises(InputError, match="a_file is a file, not a folder"):
        prepare_output_folder(a_file / "sub" / "deeper")
    with pytest.raises(InputError, match="is the folder of the input"):
        prepare_output_folder(tmp_path, inputs=(a_file,))
    assert prepare_output_folder(tmp_path / "new" / "out").is_dir()
    with pytest.raises(InputError, match="--json: is a folder"):
        prepare_output_file(tmp_path, "--json")
    with pytest.raises(InputError, match=r"--json: cannot be written: .*a_file is a file"):
        prepare_output_file(a_file / "x.json", "--json")
    assert prepare_output_file(tmp_path / "deep" / "x.json").parent.is_dir()


def test_measure_into_a_file_or_under_one_is_one_line(dataset, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me")
    _one_error_line(runner.invoke(app, _measure(dataset, "--out", str(a_file))), "a_file", "--out")
    _one_error_line(runner.invoke(app, _measure(dataset, "--out", str(a_file / "sub"))), "--out",
                    "is a file, not a folder")
    assert a_file.read_text() == "keep me"


def test_measure_never_writes_over_its_inputs(dataset):
    """A report is <stem>.json and an overlay <stem>.png: written into the frame's own folder
    they would replace the frame's metadata and image."""
    frame = dataset / "frames" / "000000.json"
    before = frame.read_bytes()
    result = runner.invoke(app, _measure(dataset, "--out", str(dataset / "frames")))
    _one_error_line(result, "--out", "is the folder of the input")
    assert frame.read_bytes() == before
    result = runner.invoke(app, ["measure", str(dataset), "--masks", str(dataset / "labels"),
                                 "--out", str(dataset / "images"), "--no-tables"])
    _one_error_line(result, "--out", "is the folder of the input")


def test_run_into_its_own_input_folder_is_refused(tmp_path):
    """A second run would read the first one's run.json as a frame."""
    flat = tmp_path / "flat"
    flat.mkdir()
    for stem in ("000000", "000001"):
        shutil.copy(SAMPLES / "frames" / f"{stem}.json", flat)
    result = runner.invoke(app, ["run", str(flat), "--out", str(flat)])
    _one_error_line(result, "--out", "is the folder of the input")
    assert sorted(p.name for p in flat.iterdir()) == ["000000.json", "000001.json"]


def test_demo_into_a_file_is_one_line(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    _one_error_line(runner.invoke(app, ["demo", "--out", str(a_file / "demo")]), "--out")


def test_telemetry_outputs_that_cannot_be_written(tmp_path):
    result = runner.invoke(app, ["telemetry", "video", str(LOGS / "flight.SRT"), "--vessel-track",
                                 str(LOGS / "ship.nmea"), "--camera", "dji-mavic3", "--frames",
                                 "48", "--fps", "2", "--image-size", "640x360",
                                 "--video-start", "2026-05-01T12:00:00Z", "--water-level-m", "0",
                                 "--out", str(tmp_path)])
    _one_error_line(result, "--out", "is a folder")
    result = runner.invoke(app, ["telemetry", "show", str(LOGS / "ship.nmea"), "--json",
                                 str(tmp_path)])
    _one_error_line(result, "--json", "is a folder")


def test_evaluation_outputs_are_checked_before_the_work(dataset, tmp_path):
    result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(dataset),
                                 "--predictions", str(dataset / "labels"), "--split", "demo",
                                 "--json", str(tmp_path)])
    _one_error_line(result, "--json", "is a folder")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(dataset),
                                 "--predictions", str(dataset / "labels"), "--split", "demo",
                                 "--markdown", str(a_file / "table.md")])
    _one_error_line(result, "--markdown")
    result = runner.invoke(app, ["evaluate", "distance", "--data", str(dataset), "--out", str(a_file)])
    _one_error_line(result, "--out", "not a folder")


@pytest.mark.parametrize("args, option", [
    (["--pose-margin-px", "10000"], "--pose-margin-px"),       # minutes and gigabytes before
    (["--own-rim-px", "10000"], "--own-rim-px"),
    (["--section-length-m", "1e308"], "--section-length-m"),
])
def test_measurement_options_have_upper_bounds(dataset, args, option):
    result = runner.invoke(app, _measure(dataset, "--out", str(dataset / "out"), *args))
    assert result.exit_code == 2, result.output
    assert option in result.output and "Traceback" not in result.output


@pytest.mark.parametrize("args, option", [
    (["models", "--num-classes", "1000000000"], "--num-classes"),
    (["evaluate", "segmentation", "--data", "x", "--predictions", "y", "--threads", "0"], "--threads"),
    (["evaluate", "segmentation", "--data", "x", "--predictions", "y", "--fps-seconds", "1e308"],
     "--fps-seconds"),
    (["contact-sheet", "x", "--tile-width", "1000000000"], "--tile-width"),
])
def test_other_options_have_bounds(args, option):
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert option in result.output and "Traceback" not in result.output


def test_a_tiny_height_bin_is_refused(dataset):
    result = runner.invoke(app, ["evaluate", "segmentation", "--data", str(dataset),
                                 "--predictions", str(dataset / "labels"), "--split", "demo",
                                 "--height-bin-m", "1e-308"])
    _one_error_line(result, "--height-bin-m")


@pytest.mark.parametrize("size", ["9" * 5000 + "x360", "1000000x360", "640x0"])
def test_an_absurd_image_size_is_one_line(tmp_path, size):
    result = runner.invoke(app, ["telemetry", "video", str(LOGS / "flight.SRT"), "--vessel-track",
                                 str(LOGS / "ship.nmea"), "--camera", "dji-mavic3", "--frames",
                                 "48", "--fps", "2", "--image-size", size, "--video-start",
                                 "2026-05-01T12:00:00Z", "--water-level-m", "0",
                                 "--out", str(tmp_path / "x.jsonl")])
    _one_error_line(result, "--image-size")


@pytest.mark.parametrize("start", ["9999-12-31T23:59:59-01:00", "0001-01-01T00:00:00+01:00", "noon"])
def test_a_video_start_outside_the_calendar_is_one_line(tmp_path, start):
    result = runner.invoke(app, ["telemetry", "video", str(LOGS / "flight.SRT"), "--vessel-track",
                                 str(LOGS / "ship.nmea"), "--camera", "dji-mavic3", "--frames",
                                 "48", "--fps", "2", "--image-size", "640x360", "--video-start",
                                 start, "--water-level-m", "0", "--out", str(tmp_path / "x.jsonl")])
    _one_error_line(result, "--video-start")

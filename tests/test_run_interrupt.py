"""Ctrl-C (SIGINT) during `harborsight run`: one line, exit code 130, and run.json's counts
equal to what is on disk (issue #30)."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from datetime import datetime, timedelta
from importlib import resources
from pathlib import Path

import cv2
import pytest

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
VESSEL = SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml"
COPIES = 5          # the bundled 48-frame flight five times over: 240 frames, a few seconds


def _long_flight(root: Path) -> Path:
    """The bundled flight repeated :data:`COPIES` times, one after the other in time."""
    flight = root / "flight"
    for sub in ("frames", "images", "labels"):
        (flight / sub).mkdir(parents=True)
    for copy in range(COPIES):
        for meta_path in sorted((SAMPLES / "flight" / "frames").glob("*.json")):
            meta = json.loads(meta_path.read_text())
            stem = f"{copy}{meta_path.stem[1:]}"
            image = SAMPLES / "flight" / "images" / meta["image"]
            shutil.copy(image, flight / "images" / f"{stem}{image.suffix}")
            shutil.copy(SAMPLES / "flight" / "labels" / f"{meta_path.stem}.png",
                        flight / "labels" / f"{stem}.png")
            meta["image"] = f"{stem}{image.suffix}"
            when = datetime.fromisoformat(meta["timestamp"]) + timedelta(seconds=30 * copy)
            meta["timestamp"] = when.isoformat()
            meta.pop("vessel_spec", None)
            (flight / "frames" / f"{stem}.json").write_text(json.dumps(meta))
    return flight


def _interrupted_after_three_reports(args: list[str], reports_dir: Path) -> tuple[int, str, str]:
    """Start ``harborsight ARGS``, send SIGINT once three reports are in ``reports_dir``, and
    return its exit code, stdout and stderr."""
    process = subprocess.Popen(
        [sys.executable, "-m", "harborsight.cli", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        deadline = time.monotonic() + 120
        while len(list(reports_dir.glob("*.json"))) < 3:
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "no report written in 120 s"
            time.sleep(0.02)
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    return process.returncode, stdout, stderr


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_stops_the_run_with_its_record_equal_to_the_disk(tmp_path):
    flight = _long_flight(tmp_path)
    total = len(list((flight / "frames").glob("*.json")))
    out = tmp_path / "out"
    returncode, stdout, stderr = _interrupted_after_three_reports(
        ["run", str(flight), "--masks", str(flight / "labels"), "--vessel", str(VESSEL),
         "--out", str(out)], out / "reports")
    assert returncode == 130, (stdout, stderr)
    assert "Traceback" not in stderr and "Aborted" not in stderr
    [line] = [line for line in stderr.splitlines() if line.strip()]
    record = json.loads((out / "run.json").read_text())
    assert line == (f"interrupted: {record['measured']} of {record['frames']} frame(s) measured "
                    f"before Ctrl-C; the outputs so far and run.json are in {out}")
    assert (record["completed"], record["aborted"]) == (False, "KeyboardInterrupt")
    reports = sorted(p.stem for p in (out / "reports").glob("*.json"))
    assert 3 <= record["measured"] == len(reports) < total
    assert record["frames"] == record["measured"] and record["skipped"] == 0
    assert sorted(p.stem for p in (out / "overlays").glob("*.png")) == reports
    n_sections = len(json.loads((out / "reports" / f"{reports[0]}.json").read_text())["sections"])
    rows = list(csv.DictReader((out / "sections.csv").open()))
    assert len(rows) == n_sections * record["measured"]
    assert {Path(row["image"]).stem for row in rows} == set(reports)
    video = cv2.VideoCapture(str(out / "annotated.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == record["measured"]
    video.release()
    assert not list(out.rglob("*.part"))
    progress = [line for line in stdout.splitlines() if line.startswith("run: ")]
    assert progress[-1].startswith(f"run: {record['frames']}/{total} frames, "), stdout


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_stops_measure_after_the_frame_in_hand(tmp_path):
    flight = _long_flight(tmp_path)
    total = len(list((flight / "frames").glob("*.json")))
    out = tmp_path / "out"
    returncode, stdout, stderr = _interrupted_after_three_reports(
        ["measure", str(flight), "--vessel", str(VESSEL), "--out", str(out), "--no-tables"], out)
    assert returncode == 130, (stdout, stderr)
    assert "Traceback" not in stderr and "Aborted" not in stderr
    reports = sorted(p.stem for p in out.glob("*.json"))
    assert 3 <= len(reports) < total
    assert sorted(p.stem for p in out.glob("*.png")) == reports
    [line] = [line for line in stderr.splitlines() if line.strip()]
    assert line == (f"interrupted: {len(reports)} of {total} frame(s) measured before Ctrl-C; "
                    f"the reports and overlays so far are in {out}")
    assert not list(out.glob("*.part"))
    progress = [line for line in stdout.splitlines() if line.startswith("measure: ")]
    assert progress[-1].startswith(f"measure: {len(reports)}/{total} frames, "), stdout

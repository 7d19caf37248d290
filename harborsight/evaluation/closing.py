"""Closing speeds of a run against a simulated flight's ground truth.

The true closing speed of section k between frames i-1 and i+1 is the central difference of
its ground-truth clearance, ``-(d_k[i+1] - d_k[i-1]) / (t[i+1] - t[i-1])``, where i-1 and
i+1 are the neighbouring frames of the same scene (a flight dataset may hold several scenes,
each with its own clock from 0); the simulator moves the vessel at a constant velocity, so
while it moves this is exact. Compared at the frames where the run measured a closing speed
for its closest section (the section nearest an obstacle, whether or not it has a speed)
and the vessel was moving on both sides.
"""

from __future__ import annotations

import csv
import json
import statistics
from dataclasses import dataclass
from pathlib import Path

from harborsight.errors import InputError


@dataclass(frozen=True)
class ClosingSpeedComparison:
    measured_mps: float          # median over the compared frames
    true_mps: float              # median over the compared frames
    median_abs_error_mps: float
    samples: int


def _ground_truth(frames_dir: Path) -> dict[str, dict]:
    """image name -> that frame's ground truth (frames without a sequence, or whose JSON
    cannot be read, are left out: the run reports those)."""
    truth = {}
    for path in sorted(frames_dir.glob("*.json")):
        try:
            meta = json.loads(path.read_text())
            gt = meta.get("ground_truth") or {}
            if "sequence" in gt and isinstance(gt.get("sections"), list):
                truth[str(meta["image"])] = gt
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
    return truth


def compare_closing_speeds(flight_dir: Path, sections_csv: Path) -> ClosingSpeedComparison | None:
    """Measured vs true closing speed of each frame's closest section (module docstring);
    None when the flight carries no sequence ground truth or nothing could be compared."""
    truth = _ground_truth(flight_dir / "frames")
    if not truth or not sections_csv.is_file():
        return None
    def scene_and_frame(image: str) -> tuple[int, int]:
        sequence = truth[image]["sequence"]
        return int(sequence.get("scene", 0)), int(sequence["frame"])

    by_key = {scene_and_frame(image): image for image in truth}
    closest: dict[str, dict] = {}
    with sections_csv.open(newline="") as handle:
        rows = [row for row in csv.DictReader(handle) if row.get("image") in truth]
    sections_of: dict[str, int] = {}
    for row in rows:
        sections_of[row["image"]] = sections_of.get(row["image"], 0) + 1
    for image, n in sections_of.items():
        if n != len(truth[image]["sections"]):
            raise InputError(sections_csv, "section", f"{image}: the run measured {n} sections, "
                             f"its ground truth has {len(truth[image]['sections'])}: compare "
                             "a run made with the vessel spec's own sections")
    for row in rows:
        if row["distance_m"]:
            best = closest.get(row["image"])
            if best is None or float(row["distance_m"]) < float(best["distance_m"]):
                closest[row["image"]] = row
    measured, true, errors = [], [], []
    for image, row in closest.items():
        if not row["closing_speed_mps"]:
            continue
        scene, frame = scene_and_frame(image)
        if (scene, frame - 1) not in by_key or (scene, frame + 1) not in by_key:
            continue
        before, after = truth[by_key[scene, frame - 1]], truth[by_key[scene, frame + 1]]
        if not (before["sequence"]["speed_mps"] and after["sequence"]["speed_mps"]):
            continue
        k = int(row["section"])
        d0 = before["sections"][k]["distance_m"]
        d1 = after["sections"][k]["distance_m"]
        if d0 is None or d1 is None:
            continue
        dt = after["sequence"]["time_s"] - before["sequence"]["time_s"]
        v_true = -(d1 - d0) / dt
        v_measured = float(row["closing_speed_mps"])
        measured.append(v_measured)
        true.append(v_true)
        errors.append(abs(v_measured - v_true))
    if not measured:
        return None
    return ClosingSpeedComparison(statistics.median(measured), statistics.median(true),
                                  statistics.median(errors), len(measured))

"""A run (``harborsight run``) against a simulated flight's ground truth: its distances, per
frame and filtered by the tracker, and its closing speeds.

**Distances.** A section of a frame counts as an estimate where the run reports it ``ok``
and the ground truth gives it a distance (as ``evaluate distance`` counts them); ``missed``
are sections the run calls ``clear`` with an obstacle in the truth, ``false`` those it
measures with none. The frames before ``from_frame`` of each scene are left out: a tracker
starts from its first readings. The errors are ``|distance_m - d|`` (per frame) and
``|filtered_distance_m - d|`` (the tracker's), ``d`` the true distance; the bars' shares are
those of ``evaluate distance`` (the truth within ``distance_m ± sigma_m`` and ``± 2 sigma_m``,
and at or above ``distance_lower_m``), over frames whose pose the image does not contradict:
with a right Gaussian sigma 68 % and 95 % lie within one and two sigma, and a bar sized for
rare gross errors shows as far more than 68 % within one.

**Closing speeds.** The true closing speed of section k between frames i-1 and i+1 is the
central difference of its ground-truth clearance, ``-(d_k[i+1] - d_k[i-1]) / (t[i+1] -
t[i-1])``, where i-1 and i+1 are the neighbouring frames of the same scene (a flight dataset
may hold several scenes, each with its own clock from 0); the simulator moves the vessel at a
constant velocity, so while it moves this is exact. Compared at the frames where the run
measured a closing speed for its closest section (the section nearest an obstacle, whether
or not it has a speed) and the vessel was moving on both sides. Where the truth has the
vessel lying still (at its berth after the approach), the closest section's closing speed
should be 0: its median magnitude there is reported too (a filter that lags a stop shows a
closing vessel, and a time to contact, at the berth).
"""

from __future__ import annotations

import csv
import json
import math
import statistics
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harborsight.errors import InputError


@dataclass(frozen=True)
class ClosingSpeedComparison:
    measured_mps: float          # median over the compared frames
    true_mps: float              # median over the compared frames
    median_abs_error_mps: float
    samples: int


@dataclass(frozen=True)
class FlightScore:
    """One scene of a flight dataset (a berthing flight), scored (module docstring)."""

    scene: int
    altitude_m: float            # the drone's median true height above the water
    frames: int                  # in the ground truth
    frames_measured: int         # with rows in the run's sections.csv
    estimates: int               # sections compared, from ``from_frame`` on
    mae_m: float | None
    mae_filtered_m: float | None
    median_abs_error_m: float | None
    p95_abs_error_m: float | None
    within_2_sigma_share: float | None
    lower_bound_share: float | None
    missed: int
    false: int
    closing: ClosingSpeedComparison | None
    #: the closest section's closing speed shown while the vessel lies still (frames whose
    #: truth has no speed, from ``from_frame``): median of its magnitude, and how many frames
    still_speed_mps: float | None = None
    still_frames: int = 0
    #: share of the estimates within one reported sigma of the truth (0.68 for a right
    #: Gaussian sigma)
    within_sigma_share: float | None = None


@dataclass(frozen=True)
class _Truth:
    scene: int
    frame: int
    height_m: float
    ground_truth: dict


def _true_height_m(meta: dict) -> float:
    """The drone's true height above the water: ``ground_truth.true_pose`` in frames with
    sensor noise, else the frame's own ``uav.alt_m`` less ``water_level_m``."""
    pose = (meta.get("ground_truth") or {}).get("true_pose") or meta
    try:
        return float(pose["uav"]["alt_m"]) - float(meta.get("water_level_m") or 0.0)
    except (KeyError, TypeError, ValueError):
        return math.nan


def _ground_truth(frames_dir: Path) -> dict[str, _Truth]:
    """image name -> that frame's ground truth (frames without a sequence, or whose JSON
    cannot be read, are left out: the run reports those)."""
    truth = {}
    for path in sorted(frames_dir.glob("*.json")):
        try:
            meta = json.loads(path.read_text())
            gt = meta.get("ground_truth") or {}
            if "sequence" in gt and isinstance(gt.get("sections"), list):
                sequence = gt["sequence"]
                truth[str(meta["image"])] = _Truth(int(sequence.get("scene", 0)),
                                                   int(sequence["frame"]), _true_height_m(meta), gt)
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
    return truth


def _run_rows(sections_csv: Path, truth: dict[str, _Truth],
              columns: tuple[str, ...] = ("image", "section", "distance_m")) -> list[dict]:
    """The run's rows of the frames in ``truth``, each ``section`` an index into the frame's
    ground truth; refused when a column of ``columns`` is absent or the run measured other
    sections than the ground truth has."""
    with sections_csv.open(newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [c for c in columns if c not in (reader.fieldnames or ())]
        if missing:
            raise InputError(sections_csv, missing[0], "no such column: not a sections.csv of "
                             "harborsight run")
        rows = [row for row in reader if row.get("image") in truth]
    sections_of: dict[str, int] = {}
    for row in rows:
        sections_of[row["image"]] = sections_of.get(row["image"], 0) + 1
    for image, n in sections_of.items():
        if n != len(truth[image].ground_truth["sections"]):
            raise InputError(sections_csv, "section", f"{image}: the run measured {n} sections, "
                             f"its ground truth has {len(truth[image].ground_truth['sections'])}: "
                             "compare a run made with the vessel spec's own sections")
    for row in rows:
        n, text = len(truth[row["image"]].ground_truth["sections"]), row["section"]
        try:
            row["section"] = int(text)
        except (TypeError, ValueError):
            row["section"] = -1
        if not 0 <= row["section"] < n:
            raise InputError(sections_csv, "section", f"{row['image']}: section {text!r} is "
                             f"not one of the {n} of its ground truth")
    return rows


def _number(row: dict, field: str, sections_csv: Path) -> float | None:
    """``row[field]`` as a float, None when empty or absent."""
    text = row.get(field)
    if text in (None, ""):
        return None
    try:
        return float(text)
    except ValueError:
        raise InputError(sections_csv, field, f"{row.get('image')}: {text!r} is not a number"
                         ) from None


def compare_closing_speeds(flight_dir: Path, sections_csv: Path, scene: int | None = None
                           ) -> ClosingSpeedComparison | None:
    """Measured vs true closing speed of each frame's closest section (module docstring),
    of every scene or of ``scene`` only; None when the flight carries no sequence ground
    truth or nothing could be compared."""
    truth = _ground_truth(flight_dir / "frames")
    if not truth or not sections_csv.is_file():
        return None
    return _closing_speeds(truth, _run_rows(sections_csv, truth), sections_csv, scene)


def _closest_rows(rows: list[dict], sections_csv: Path) -> dict[str, dict]:
    """image -> the row of its closest section (the least ``distance_m``) among ``rows``."""
    closest: dict[str, tuple[float, dict]] = {}
    for row in rows:
        distance = _number(row, "distance_m", sections_csv)
        if distance is not None and (row["image"] not in closest
                                     or distance < closest[row["image"]][0]):
            closest[row["image"]] = (distance, row)
    return {image: row for image, (_, row) in closest.items()}


def _closing_speeds(truth: dict[str, _Truth], rows: list[dict], sections_csv: Path,
                    scene: int | None) -> ClosingSpeedComparison | None:
    by_key = {(t.scene, t.frame): image for image, t in truth.items()}
    closest = _closest_rows(
        [row for row in rows if scene is None or truth[row["image"]].scene == scene], sections_csv)
    measured, true, errors = [], [], []
    for image, row in closest.items():
        v_measured = _number(row, "closing_speed_mps", sections_csv)
        if v_measured is None:
            continue
        here = truth[image]
        neighbours = (by_key.get((here.scene, here.frame - 1)), by_key.get((here.scene, here.frame + 1)))
        if None in neighbours:
            continue
        before, after = (truth[image].ground_truth for image in neighbours)
        if not (before["sequence"]["speed_mps"] and after["sequence"]["speed_mps"]):
            continue
        k = row["section"]
        d0 = before["sections"][k]["distance_m"]
        d1 = after["sections"][k]["distance_m"]
        if d0 is None or d1 is None:
            continue
        dt = after["sequence"]["time_s"] - before["sequence"]["time_s"]
        v_true = -(d1 - d0) / dt
        measured.append(v_measured)
        true.append(v_true)
        errors.append(abs(v_measured - v_true))
    if not measured:
        return None
    return ClosingSpeedComparison(statistics.median(measured), statistics.median(true),
                                  statistics.median(errors), len(measured))


def _still_speed(truth: dict[str, _Truth], rows: list[dict], sections_csv: Path, scene: int,
                 from_frame: int) -> dict:
    """``still_speed_mps`` and ``still_frames`` of :class:`FlightScore`: at each frame of
    ``scene`` whose truth has no speed, the closing speed of the frame's closest section
    (when it has one)."""
    def still(here: _Truth) -> bool:
        return (here.scene == scene and here.frame >= from_frame
                and not here.ground_truth["sequence"].get("speed_mps"))

    closest = _closest_rows([row for row in rows if still(truth[row["image"]])], sections_csv)
    speeds = [abs(v) for row in closest.values()
              if (v := _number(row, "closing_speed_mps", sections_csv)) is not None]
    return {"still_speed_mps": statistics.median(speeds) if speeds else None,
            "still_frames": len(speeds)}


def score_flight(flight_dir: Path, sections_csv: Path, from_frame: int = 3) -> list[FlightScore]:
    """Each scene of the flight dataset ``flight_dir`` (``frames/*.json`` with sequence
    ground truth) against the run's ``sections.csv`` (module docstring), in scene order."""
    truth = _ground_truth(flight_dir / "frames")
    if not truth:
        raise InputError(flight_dir / "frames", "ground_truth.sequence",
                         "no frame carries a flight's ground truth (simulate --sequence-frames)")
    if not sections_csv.is_file():
        raise InputError(sections_csv, None, "no such file (the run's sections.csv)")
    rows = _run_rows(sections_csv, truth, ("image", "section", "status", "distance_m"))
    scores = []
    for scene in sorted({t.scene for t in truth.values()}):
        images = {image for image, t in truth.items() if t.scene == scene}
        errors, filtered, within, within_one, above = [], [], [], [], []
        missed = false = 0
        for row in rows:
            here = truth[row["image"]]
            if here.scene != scene or here.frame < from_frame:
                continue
            d_true = here.ground_truth["sections"][row["section"]]["distance_m"]
            status = row.get("status")
            if status == "clear" and d_true is not None:
                missed += 1
            if status != "ok":
                continue
            if d_true is None:
                false += 1
                continue
            distance = _number(row, "distance_m", sections_csv)
            if distance is None:
                raise InputError(sections_csv, "distance_m", f"{row['image']}: an ok section "
                                 f"({row['section']}) without a distance")
            errors.append(abs(distance - d_true))
            smoothed = _number(row, "filtered_distance_m", sections_csv)
            if smoothed is not None:
                filtered.append(abs(smoothed - d_true))
            if row.get("pose_contradicted") not in ("1", "True", "true"):
                sigma = _number(row, "sigma_m", sections_csv)
                lower = _number(row, "distance_lower_m", sections_csv)
                if sigma is not None:
                    within.append(abs(distance - d_true) <= 2.0 * sigma)
                    within_one.append(abs(distance - d_true) <= sigma)
                if lower is not None:
                    above.append(d_true >= lower)
        heights = [truth[image].height_m for image in images]
        scores.append(FlightScore(
            scene=scene, altitude_m=float(np.nanmedian(heights)) if heights else math.nan,
            frames=len(images), frames_measured=len({r["image"] for r in rows} & images),
            estimates=len(errors),
            mae_m=float(np.mean(errors)) if errors else None,
            mae_filtered_m=float(np.mean(filtered)) if filtered else None,
            median_abs_error_m=float(np.median(errors)) if errors else None,
            p95_abs_error_m=float(np.percentile(errors, 95)) if errors else None,
            within_2_sigma_share=float(np.mean(within)) if within else None,
            lower_bound_share=float(np.mean(above)) if above else None,
            missed=missed, false=false,
            closing=_closing_speeds(truth, rows, sections_csv, scene),
            **_still_speed(truth, rows, sections_csv, scene, from_frame),
            within_sigma_share=float(np.mean(within_one)) if within_one else None))
    return scores

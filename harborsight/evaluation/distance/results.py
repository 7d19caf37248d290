"""Each frame measured and each section classed against the simulator's truth (estimate,
missed, unseen, false; the package docstring), with the reported obstacle point traced in the
simulator's own masks and the true nearest obstacle's kind; and the frames read with their
ground truth checked."""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.clearance.measure import ClearanceSettings, measure_frame
from harborsight.clearance.report import STATUS_CLEAR, STATUS_OK
from harborsight.errors import HarborsightError, InputError
from harborsight.evaluation.distance.masks import MaskSource, oracle_masks, scene_planner, split_mask
from harborsight.frame import parse_frame_metadata
from harborsight.vessel.spec import VesselSpec, load_vessel_spec


@dataclass
class SectionResult:
    frame: str
    altitude_m: float
    masks: str
    method: str
    section: int
    status: str
    estimate_m: float | None
    truth_m: float | None
    gsd_m_per_px: float
    contact: bool
    truncated: bool
    obstacle: str | None = None      # kind of the true nearest obstacle (when attributed)
    point_truth: str | None = None   # what the reported obstacle point really is (POINT_TRUTHS)
    sigma_m: float | None = None     # the report's one sigma and 95 % lower bound
    lower_m: float | None = None
    #: how far out a ``clear`` section saw its band's water (the report's ``clear_to_m``;
    #: None where the band does not leave the picture)
    clear_to_m: float | None = None
    #: the frame's pose is one the image contradicts (``sensors_contradicted``)
    flagged: bool = False

    def within_sigmas(self, count: float) -> bool | None:
        """Whether the estimate is within ``count`` reported sigmas of the truth (None for a
        flagged frame, whose sigma is raised to the reading by construction)."""
        if self.kind != "estimate" or self.sigma_m is None or self.flagged:
            return None
        return abs(self.estimate_m - self.truth_m) <= count * self.sigma_m

    @property
    def lower_bound_holds(self) -> bool | None:
        """Whether the true distance is at least the reported lower bound (None for a flagged
        frame, whose bound is 0 by construction)."""
        if self.kind != "estimate" or self.lower_m is None or self.flagged:
            return None
        return self.truth_m >= self.lower_m

    @property
    def kind(self) -> str:
        if self.status == STATUS_OK and self.truth_m is not None:
            return "estimate"
        if self.status == STATUS_CLEAR and self.truth_m is not None:
            return "unseen" if self.clear_to_m == 0.0 else "missed"
        if self.status == STATUS_OK and self.truth_m is None:
            return "false"
        return "none"

    @property
    def abs_error_m(self) -> float | None:
        if self.kind != "estimate":
            return None
        return abs(self.estimate_m - self.truth_m)

    @property
    def signed_error_px(self) -> float | None:
        """``(estimate - truth) / GSD``: positive where the gap is overestimated."""
        if self.kind != "estimate":
            return None
        return (self.estimate_m - self.truth_m) / self.gsd_m_per_px


#: obstacle points within this many pixels of a truly solid pixel count as on the obstacle
POINT_TOLERANCE_PX = 2
#: what a reported obstacle point lies on, in the simulator's masks (module docstring)
POINT_TRUTHS = ("obstacle", "vessel-spill", "false-solid")


def true_obstacle_mask(dataset: Path, frame: dict) -> np.ndarray | None:
    """uint8 mask (1 = solid) of every object but the vessel of interest, grown by
    :data:`POINT_TOLERANCE_PX` (square), from the frame's labels and instances; ``ignore``
    counts as solid. None when the dataset has no labels for the frame."""
    try:
        labels = oracle_masks(dataset, frame)
    except HarborsightError:
        return None
    solid = labels != 0
    instances_path = dataset / "instances" / f"{Path(frame['image']).stem}.png"
    instances = (cv2.imread(str(instances_path), cv2.IMREAD_UNCHANGED)
                 if instances_path.is_file() else None)
    if instances is not None and instances.shape == labels.shape:
        solid &= instances != 1                  # instance 1 is the vessel of interest
    size = 2 * POINT_TOLERANCE_PX + 1
    return cv2.dilate(solid.astype(np.uint8), np.ones((size, size), np.uint8))


def obstacle_point_truth(near_obstacle: np.ndarray, point_px, contact: bool) -> str:
    """:data:`POINT_TRUTHS` entry for a reported obstacle point ``(u, v)``, given
    :func:`true_obstacle_mask`."""
    h, w = near_obstacle.shape
    u = min(max(round(float(point_px[0])), 0), w - 1)
    v = min(max(round(float(point_px[1])), 0), h - 1)
    if near_obstacle[v, u]:
        return "obstacle"
    return "vessel-spill" if contact else "false-solid"


def truth_obstacle_kinds(dataset: Path) -> Callable[[dict], list[str | None]]:
    """``kinds(frame)``: per section, the kind of the simulator object (``SceneObject.kind``)
    that the frame's ground-truth ``distance_m`` is measured to, None where none is in view.
    The scene is rebuilt from the dataset's seed and parameters (no bpy; about 0.3 s a frame)."""
    from harborsight.sim.ground_truth import nearest_visible_obstacle

    plan = scene_planner(dataset)

    def kinds(frame: dict) -> list[str | None]:
        scene, vessel = plan(frame)
        others = scene.objects[1:]      # objects[0] is the vessel of interest
        geometry = scene.geometry()     # the true pose, as the truth was taken with
        nearest = nearest_visible_obstacle(geometry, vessel, [o.footprint() for o in others],
                                           len(frame["ground_truth"]["sections"]))
        return [None if i is None else others[i].kind for i in nearest]
    return kinds


def attribute_obstacles(results: list[SectionResult], kinds: dict[str, list[str | None]]) -> None:
    """Set each result's ``obstacle`` from ``kinds[frame][section]`` (frames not in ``kinds``
    are left as they are)."""
    for r in results:
        if r.frame in kinds:
            r.obstacle = kinds[r.frame][r.section]


def evaluate_frames(
    dataset: Path, frames: Iterable[dict], masks_name: str, masks: MaskSource, method: str,
    on_frame: Callable[[str, str | None], None] | None = None,
    clearance: ClearanceSettings | None = None,
) -> list[SectionResult]:
    """Measure every frame with ``masks`` and ``method`` (the rest of the settings from
    ``clearance``); a bad frame is reported and skipped."""
    settings = dataclasses.replace(clearance or ClearanceSettings(), method=method)
    vessels: dict[str, VesselSpec] = {}
    results: list[SectionResult] = []
    for frame in frames:
        stem = Path(frame["image"]).stem
        frame_path = dataset / "frames" / f"{stem}.json"
        try:
            meta = parse_frame_metadata(frame, frame_path, base_dir=dataset / "frames")
            spec_path = frame.get("vessel_spec")
            if not isinstance(spec_path, str) or not spec_path:
                raise InputError(frame_path, "vessel_spec", f"expected the vessel.yaml path "
                                 f"in the dataset, got {spec_path!r}")
            if spec_path not in vessels:
                vessels[spec_path] = load_vessel_spec(dataset / spec_path)
            truth = frame["ground_truth"]["sections"]
            labels, confidence = split_mask(masks(dataset, frame))
            report = measure_frame(labels, meta, vessels[spec_path], settings,
                                   mask_from_file=masks is oracle_masks, confidence=confidence)
            if len(report.sections) != len(truth):
                raise HarborsightError(f"{frame_path}: {len(report.sections)} sections measured, "
                                       f"{len(truth)} in the ground truth")
            near_obstacle = true_obstacle_mask(dataset, frame)
        except HarborsightError as exc:
            if on_frame:
                on_frame(stem, str(exc))
            continue
        except Exception as exc:  # one bad frame must not end the evaluation
            if on_frame:
                on_frame(stem, f"{frame_path}: {type(exc).__name__}: {exc}")
            continue
        altitude = round(_true_height_m(frame, meta.height_above_water_m))
        for s, t in zip(report.sections, truth, strict=True):
            if s.status not in (STATUS_OK, STATUS_CLEAR):
                continue
            point_truth = None
            if near_obstacle is not None and s.status == STATUS_OK and s.obstacle_point_px:
                point_truth = obstacle_point_truth(near_obstacle, s.obstacle_point_px, s.contact)
            results.append(SectionResult(
                stem, altitude, masks_name, method, s.index, s.status, s.distance_m,
                t["distance_m"], report.gsd_m_per_px, bool(s.contact), bool(s.truncated),
                point_truth=point_truth, sigma_m=s.sigma_m, lower_m=s.distance_lower_m,
                clear_to_m=s.clear_to_m, flagged=report.sensors_contradicted))
        if on_frame:
            on_frame(stem, None)
    return results


def _true_height_m(frame: dict, measured_m: float) -> float:
    """The drone's true height above the water: from ``ground_truth.true_pose`` in frames
    with sensor noise (``dataset add-pose-noise``), else the frame's own."""
    true_pose = (frame.get("ground_truth") or {}).get("true_pose") or {}
    try:
        return float(true_pose["uav"]["alt_m"]) - float(frame.get("water_level_m") or 0.0)
    except (KeyError, TypeError, ValueError):
        return measured_m


def load_frames(dataset: Path, split: str | None = None,
                problems: list[tuple[str, str]] | None = None) -> list[dict]:
    """Frame documents of a dataset (optionally one split of dataset.json), sorted. A file
    that is not a frame with ground truth is left out and, with ``problems``, listed there
    as ``(path, reason)``; a bad dataset.json raises :class:`InputError`."""
    wanted = None
    if split:
        index_path = dataset / "dataset.json"
        try:
            doc = json.loads(index_path.read_text())
            wanted = {stem for stem, s in doc["split"].items() if s == split}
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise InputError(index_path, "split", f"cannot read the split table: "
                             f"{type(exc).__name__}: {exc}") from None
    frames = []
    for path in sorted((dataset / "frames").glob("*.json")):
        if wanted is not None and path.stem not in wanted:
            continue
        try:
            frames.append(_frame_with_truth(path))
        except InputError as exc:
            if problems is not None:
                problems.append((str(path), str(exc)))
    return frames


def _frame_with_truth(path: Path) -> dict:
    """One frame JSON with the fields the evaluation reads checked (``image``,
    ``ground_truth.sections[].distance_m``); the rest is checked when it is measured."""
    try:
        frame = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(path, None, f"not readable JSON: {exc}") from None
    if not isinstance(frame, dict):
        raise InputError(path, None, "expected a JSON object")
    if not isinstance(frame.get("image"), str) or not frame["image"]:
        raise InputError(path, "image", "missing (the image file name)")
    truth = frame.get("ground_truth")
    sections = truth.get("sections") if isinstance(truth, dict) else None
    if not isinstance(sections, list) or not sections:
        raise InputError(path, "ground_truth.sections", "missing: not a simulator frame")
    for n, section in enumerate(sections):
        value = section.get("distance_m", "missing") if isinstance(section, dict) else "missing"
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value) or value < 0):
            raise InputError(path, f"ground_truth.sections[{n}].distance_m",
                             f"expected metres (finite, not negative) or null, got {value!r}")
        if isinstance(section, dict) and section.get("index", n) != n:
            # the truth is paired with the report's sections by place: out of order, every
            # section would be scored against another's
            raise InputError(path, f"ground_truth.sections[{n}].index",
                             f"{section.get('index')!r} in place {n}: expected the sections in "
                             "order")
    return frame

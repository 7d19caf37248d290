"""Distance error against the simulator's ground truth, per altitude (the paper's Sec. IV).

Each configuration (masks: ``oracle`` = the simulator's labels or a segmentation model; method:
``gsd`` or ``ground_plane``) is run on every frame of a dataset; every section is classed as

* an **estimate** (report ``ok``, truth has a visible obstacle): absolute error in metres and in
  GSD pixels;
* a **missed obstacle** (truth has one in view, the report says ``clear`` and saw some of
  the band's water: ``clear_to_m`` above 0);
* an **unseen** section (truth has one in view, the report says ``clear`` but saw none of
  the band: ``clear_to_m`` 0, a band the vessel hides in full or a frame whose pose the image
  contradicts): the report claims nothing there, so it is not counted as missed;
* a **false obstacle** (the report says ``ok``, the truth has nothing in view in that band).

Sections out of view are not counted. Summaries are per altitude (drone height above water,
rounded to whole metres): n, MAE, median, p95, share off by more than 1 m, missed, unseen,
false. Every estimate counts in the error figures; the calibration shares (within one and two
sigma, truth at or above the lower bound) leave out the sections of frames flagged
``sensors_contradicted``, whose bars are widened to the reading by construction (their lower
bound is 0), and the summary counts those sections apart.

With the obstacle attribution (:func:`truth_obstacle_kinds`), each estimate also carries the
kind of scene object its true distance is measured to (quay, pier, ship, boat, ...), and the
signed error ``estimate - truth`` in GSD pixels is summarised per kind: the planar
assumption errs by kind of structure (an edge ``h`` m above the water, ``r`` m from the
nadir, seen from ``H`` m, back-projects ``h·r/(H-h)`` m too far out), so this separates it.

Segmentation errors are traced the same way, pixel by pixel: each reported obstacle point is
looked up in the simulator's own masks (:func:`obstacle_point_truth`). A point within
:data:`POINT_TOLERANCE_PX` of a truly solid pixel of another object is a real obstacle (its
error is geometry and edge placement); a point on true water is a segmentation mistake,
``vessel-spill`` when the solid it lies on runs into the vessel's own region (the model's
blob of the vessel reaching out over the water, e.g. onto its shadow) and ``false-solid``
otherwise (a blob of water taken for solid). :func:`summarise_error_sources` gives each
kind's share of the summed absolute error per altitude; with the obstacle attribution too,
:func:`summarise_error_budget` splits the summed error by (true obstacle kind, point truth)
and counts the misses per kind, so a whole error can be read as a budget.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.clearance.measure import ClearanceSettings, measure_frame
from harborsight.clearance.report import STATUS_CLEAR, STATUS_OK
from harborsight.errors import HarborsightError, InputError
from harborsight.files import strict_json
from harborsight.frame import parse_frame_metadata
from harborsight.perception.confidence import SolidConfidence
from harborsight.vessel.spec import VesselSpec, load_vessel_spec

#: a mask provider: (dataset dir, frame document) -> class labels (H, W) uint8, or the labels
#: and the model's probabilities behind them (a model's masks)
MaskSource = Callable[[Path, dict], "np.ndarray | tuple[np.ndarray, SolidConfidence]"]


def split_mask(mask) -> tuple[np.ndarray, SolidConfidence | None]:
    """``(labels, confidence or None)`` of what a :data:`MaskSource` gave."""
    return mask if isinstance(mask, tuple) else (mask, None)


def oracle_masks(dataset: Path, frame: dict) -> np.ndarray:
    """The simulator's exact labels."""
    stem = Path(frame["image"]).stem
    labels = cv2.imread(str(dataset / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
    if labels is None:
        raise HarborsightError(f"{dataset / 'labels' / (stem + '.png')}: missing label mask")
    return labels


def model_masks(segment: Callable, takes_gsd: bool = False) -> MaskSource:
    """Masks from a segmenter: BGR uint8 image -> class labels, or -> (labels,
    :class:`~harborsight.perception.confidence.SolidConfidence`) as
    ``OnnxSegmenter.segment_with_confidence`` gives. ``takes_gsd``: ``segment(image,
    gsd_m_per_px)`` is given each frame's GSD from its metadata
    (:func:`~harborsight.pipeline.frame_gsd_m_per_px`) (the sensors' height,
    as a run has it; :class:`~harborsight.perception.gsd_scaling.GsdScaledSegmenter`)."""
    from harborsight.frame import parse_frame_metadata
    from harborsight.images import read_image_and_no_data
    from harborsight.pipeline import frame_gsd_m_per_px, unseen_where_no_picture

    def source(dataset: Path, frame: dict) -> np.ndarray:
        image, no_data = read_image_and_no_data(dataset / "images" / frame["image"])
        if takes_gsd:
            meta = parse_frame_metadata(frame, dataset / "frames" / f"{Path(frame['image']).stem}.json",
                                        base_dir=dataset / "frames")
            mask = segment(image, frame_gsd_m_per_px(meta))
        else:
            mask = segment(image)
        if no_data is None:
            return mask
        labels, confidence = split_mask(mask)
        labels = unseen_where_no_picture(labels, confidence, no_data)
        return labels if confidence is None else (labels, confidence)
    return source


def flat_world_masks(dataset: Path) -> MaskSource:
    """Masks of a flat world: each pixel centre back-projected onto the water plane and
    labelled by the scene footprint it falls in (the simulator's scene rebuilt from the
    dataset's seed and parameters; no bpy needed).

    These masks have the rendered frame's pixel grid but no height: measuring on them leaves
    only pixel quantisation, so ``oracle`` minus ``flat`` is the planar assumption's share
    of the error (paper Sec. V, the first two error sources). The vessel of interest is
    drawn as in the frame, as the image silhouette of its whole hull: its plan footprint
    laid flat would stick out of that silhouette where the hull flares and become a false
    obstacle touching the hull."""
    plan = scene_planner(dataset)
    cache: dict[str, np.ndarray] = {}   # each method measures the same masks

    def source(dataset_dir: Path, frame: dict) -> np.ndarray:
        if frame["image"] not in cache:
            scene, vessel = plan(frame)
            # the scene's own, true pose: a dataset with sensor noise writes the noisy one in
            # the frame (its flat masks then agreed with the rendered labels on 86-88 %)
            geometry = scene.geometry()
            own, *others = scene.objects   # objects[0] is the vessel of interest
            cache[frame["image"]] = flat_world_labels(
                geometry, [(obj.footprint(), obj.class_id) for obj in others],
                vessel=(vessel, own.class_id))
        return cache[frame["image"]]
    return source


def scene_planner(dataset: Path) -> Callable[[dict], tuple]:
    """``plan(frame) -> (scene, vessel spec)``: a simulator frame's scene rebuilt from the
    dataset's seed and parameters (no bpy), with the vessel of interest's spec."""
    from harborsight.sim.dataset import SimulationConfig, plan_frame

    doc = json.loads((dataset / "dataset.json").read_text())
    config = SimulationConfig.from_dict(doc["parameters"])
    vessels = {p.parent.name: load_vessel_spec(p)
               for p in sorted((dataset / "vessels").glob("*/vessel.yaml"))}

    def plan(frame: dict) -> tuple:
        scene = plan_frame(config, int(frame["simulation"]["index"]), vessels)
        return scene, vessels[Path(frame["vessel_spec"]).parent.name]
    return plan


def flat_world_labels(geometry, footprints: list[tuple],
                      vessel: tuple[VesselSpec, int] | None = None) -> np.ndarray:
    """Class labels of pixel centres whose ray meets the water plane inside a footprint
    (later footprints win); 255 where the ray misses the plane. ``vessel`` (spec, class)
    is painted last, over the image silhouette of its hull points."""
    import shapely

    from harborsight.sim.ground_truth import vessel_silhouette

    intr = geometry.camera.intrinsics
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    ground, valid = geometry.camera.back_project_to_plane(np.column_stack((u.ravel(), v.ravel())))
    labels = np.where(valid, 0, 255).astype(np.uint8)
    x, y = ground[:, 0], ground[:, 1]
    view = shapely.box(*ground[valid, :2].min(axis=0), *ground[valid, :2].max(axis=0))
    for polygon, class_id in footprints:
        if polygon.is_empty or not polygon.intersects(view):
            continue
        box = polygon.bounds
        near = valid & (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
        inside = near.copy()
        inside[near] = shapely.contains_xy(polygon, x[near], y[near])
        labels[inside] = class_id
    if vessel is not None:
        silhouette = vessel_silhouette(vessel[0], geometry)
        labels[shapely.contains_xy(silhouette, u.ravel(), v.ravel())] = vessel[1]
    return labels.reshape(intr.height, intr.width)


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


@dataclass
class AltitudeSummary:
    altitude_m: float
    masks: str
    method: str
    n: int
    mae_m: float | None
    #: sample standard deviation of the absolute errors (n - 1 in the denominator); None below n = 2
    std_m: float | None
    median_m: float | None
    p95_m: float | None
    over_1m_share: float | None
    median_px: float | None
    missed: int
    false: int
    #: share of estimates within one and two reported sigmas of the truth (0.68 and 0.95
    #: when the sigmas are right and errors normal), share whose truth is at least the
    #: reported lower bound (0.95), and the median reported sigma
    within_sigma_share: float | None = None
    within_2_sigma_share: float | None = None
    lower_bound_share: float | None = None
    median_sigma_m: float | None = None
    #: sections with an obstacle in view whose band the report saw none of (``unseen``)
    unseen: int = 0
    #: sections (ok or clear) of frames whose pose the image contradicts: in the error
    #: figures, left out of the calibration shares
    flagged: int = 0


def _share(flags: list[bool | None]) -> float | None:
    known = [f for f in flags if f is not None]
    return float(np.mean(known)) if known else None


def summarise(results: list[SectionResult]) -> list[AltitudeSummary]:
    """Per (masks, method, altitude): error statistics and miss / false counts."""
    groups: dict[tuple, list[SectionResult]] = {}
    for r in results:
        groups.setdefault((r.masks, r.method, r.altitude_m), []).append(r)
    rows = []
    for (masks, method, altitude), group in sorted(groups.items(), key=lambda kv: kv[0]):
        errors = np.array([r.abs_error_m for r in group if r.kind == "estimate"])
        px = np.array([r.abs_error_m / r.gsd_m_per_px for r in group if r.kind == "estimate"])
        some = len(errors) > 0
        rows.append(AltitudeSummary(
            altitude, masks, method, len(errors),
            float(errors.mean()) if some else None,
            float(errors.std(ddof=1)) if len(errors) > 1 else None,
            float(np.median(errors)) if some else None,
            float(np.percentile(errors, 95)) if some else None,
            float(np.mean(errors > 1.0)) if some else None,
            float(np.median(px)) if some else None,
            sum(r.kind == "missed" for r in group), sum(r.kind == "false" for r in group),
            _share([r.within_sigmas(1) for r in group]), _share([r.within_sigmas(2) for r in group]),
            _share([r.lower_bound_holds for r in group]),
            _median([r.sigma_m for r in group if r.kind == "estimate"]),
            sum(r.kind == "unseen" for r in group), sum(r.flagged for r in group)))
    return rows


def _median(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return float(np.median(known)) if known else None


@dataclass
class ObstacleSummary:
    masks: str
    method: str
    obstacle: str
    n: int
    median_signed_px: float
    median_abs_px: float
    mae_m: float
    over_1px_share: float            # estimate - truth > +1 px (gap overestimated)
    under_1px_share: float           # estimate - truth < -1 px
    median_signed_px_by_altitude: dict[float, float]


def summarise_by_obstacle(results: list[SectionResult]) -> list[ObstacleSummary]:
    """Per (masks, method, true nearest obstacle kind): signed and absolute error in GSD
    pixels over all altitudes, and the median signed error per altitude."""
    groups: dict[tuple, list[SectionResult]] = {}
    for r in results:
        if r.kind == "estimate" and r.obstacle:
            groups.setdefault((r.masks, r.method, r.obstacle), []).append(r)
    rows = []
    for (masks, method, obstacle), group in sorted(groups.items()):
        signed = np.array([r.signed_error_px for r in group])
        by_altitude: dict[float, list[float]] = {}
        for r, e in zip(group, signed, strict=True):
            by_altitude.setdefault(r.altitude_m, []).append(e)
        rows.append(ObstacleSummary(
            masks, method, obstacle, len(group), float(np.median(signed)),
            float(np.median(np.abs(signed))), float(np.mean([r.abs_error_m for r in group])),
            float(np.mean(signed > 1.0)), float(np.mean(signed < -1.0)),
            {a: float(np.median(v)) for a, v in sorted(by_altitude.items())}))
    return rows


def markdown_obstacle_table(rows: list[ObstacleSummary]) -> str:
    """Two tables: per kind over all altitudes; median signed px per kind and altitude."""
    lines = ["| masks | method | nearest obstacle | n | median signed px | median abs px | "
             "MAE m | over > 1 px | under > 1 px |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | {r.n} | "
                     f"{r.median_signed_px:+.2f} | {r.median_abs_px:.2f} | {r.mae_m:.2f} | "
                     f"{100 * r.over_1px_share:.0f} % | {100 * r.under_1px_share:.0f} % |")
    altitudes = sorted({a for r in rows for a in r.median_signed_px_by_altitude})
    lines += ["", "Median signed error (px) by drone height above water (m):", "",
              "| masks | method | nearest obstacle | " + " | ".join(f"{a:.0f}" for a in altitudes)
              + " |", "|---|---|---|" + "---:|" * len(altitudes)]
    for r in rows:
        cells = [_fmt(r.median_signed_px_by_altitude.get(a)) for a in altitudes]
        lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


@dataclass
class ErrorSourceSummary:
    masks: str
    method: str
    altitude_m: float
    n: int                                # estimates with a traced obstacle point
    mae_m: float
    mae_on_obstacle_m: float | None       # MAE of the estimates whose point is a real obstacle
    count: dict[str, int]                 # estimates per point truth
    error_share: dict[str, float]         # share of the summed |error| per point truth
    false_obstacles: dict[str, int]       # false obstacles per point truth


def summarise_error_sources(results: list[SectionResult]) -> list[ErrorSourceSummary]:
    """Per (masks, method, altitude): how much of the absolute error comes from estimates
    whose obstacle point is a real obstacle, the vessel's own blob spilt onto water, or
    water taken for solid (module docstring); empty when no point was traced."""
    groups: dict[tuple, list[SectionResult]] = {}
    for r in results:
        if r.point_truth is not None:
            groups.setdefault((r.masks, r.method, r.altitude_m), []).append(r)
    rows = []
    for (masks, method, altitude), group in sorted(groups.items(), key=lambda kv: kv[0]):
        estimates = [r for r in group if r.kind == "estimate"]
        if not estimates:
            continue
        errors = np.array([r.abs_error_m for r in estimates])
        on_obstacle = errors[[r.point_truth == "obstacle" for r in estimates]]
        total = float(errors.sum())
        rows.append(ErrorSourceSummary(
            masks, method, altitude, len(estimates), float(errors.mean()),
            float(on_obstacle.mean()) if len(on_obstacle) else None,
            {t: sum(r.point_truth == t for r in estimates) for t in POINT_TRUTHS},
            {t: (float(sum(r.abs_error_m for r in estimates if r.point_truth == t)) / total
                 if total > 0 else 0.0) for t in POINT_TRUTHS},
            {t: sum(r.kind == "false" and r.point_truth == t for r in group) for t in POINT_TRUTHS}))
    return rows


@dataclass
class ErrorBudgetRow:
    masks: str
    method: str
    obstacle: str                     # kind of the true nearest obstacle
    point: str                        # what the reported point lies on (POINT_TRUTHS), or "missed"
    n: int                            # estimates (or missed sections) in the group
    mae_m: float | None               # None for misses: they have no distance to compare
    error_share: float                # share of the configuration's summed |error|
    wider_1m: int                     # estimates reading the gap > 1 m wider than it is
    narrower_1m: int                  # estimates reading it > 1 m narrower


def summarise_error_budget(results: list[SectionResult]) -> list[ErrorBudgetRow]:
    """Per (masks, method): the summed absolute error split by the kind of the true nearest
    obstacle and by what the reported point lies on, largest share first, then the missed
    obstacles per kind. Needs results with obstacle kinds (:func:`attribute_obstacles`);
    untraced points count as ``untraced``. A wider-than-true reading is the dangerous side."""
    configs: dict[tuple, list[SectionResult]] = {}
    for r in results:
        if r.obstacle and r.kind in ("estimate", "missed"):
            configs.setdefault((r.masks, r.method), []).append(r)
    rows: list[ErrorBudgetRow] = []
    for (masks, method), group in sorted(configs.items()):
        total = sum(r.abs_error_m for r in group if r.kind == "estimate")
        cells: dict[tuple, list[SectionResult]] = {}
        for r in group:
            point = "missed" if r.kind == "missed" else (r.point_truth or "untraced")
            cells.setdefault((r.obstacle, point), []).append(r)
        estimates, misses = [], []
        for (obstacle, point), cell in cells.items():
            if point == "missed":
                misses.append(ErrorBudgetRow(masks, method, obstacle, point, len(cell), None,
                                             0.0, 0, 0))
                continue
            signed = np.array([r.estimate_m - r.truth_m for r in cell])
            estimates.append(ErrorBudgetRow(
                masks, method, obstacle, point, len(cell), float(np.abs(signed).mean()),
                float(np.abs(signed).sum() / total) if total > 0 else 0.0,
                int((signed > 1.0).sum()), int((signed < -1.0).sum())))
        rows += sorted(estimates, key=lambda r: (-r.error_share, r.obstacle, r.point))
        rows += sorted(misses, key=lambda r: (-r.n, r.obstacle))
    return rows


def markdown_error_budget_table(rows: list[ErrorBudgetRow]) -> str:
    lines = ["| masks | method | nearest obstacle (truth) | reported point lies on | n | MAE m | "
             "share of summed error | wider by > 1 m | narrower by > 1 m |",
             "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        if r.point == "missed":
            lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | (missed) | {r.n} | — | — "
                         "| — | — |")
        else:
            lines.append(f"| {r.masks} | {r.method} | {r.obstacle} | {r.point} | {r.n} | "
                         f"{_fmt(r.mae_m)} | {100 * r.error_share:.1f} % | {r.wider_1m} | "
                         f"{r.narrower_1m} |")
    return "\n".join(lines) + "\n"


def markdown_error_source_table(rows: list[ErrorSourceSummary]) -> str:
    lines = ["| masks | method | altitude m | n | MAE m | MAE m, point on a real obstacle | "
             "error share: real obstacle | vessel spill | false solid | "
             "false obstacles: vessel spill / false solid |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        share = " | ".join(f"{100 * r.error_share[t]:.0f} % ({r.count[t]})" for t in POINT_TRUTHS)
        lines.append(f"| {r.masks} | {r.method} | {r.altitude_m:.0f} | {r.n} | {r.mae_m:.2f} | "
                     f"{_fmt(r.mae_on_obstacle_m)} | {share} | "
                     f"{r.false_obstacles['vessel-spill']} / {r.false_obstacles['false-solid']} |")
    return "\n".join(lines) + "\n"


def write_csv(results: list[SectionResult], path: Path) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["frame", "altitude_m", "masks", "method", "section", "status", "kind",
                         "estimate_m", "truth_m", "abs_error_m", "gsd_m_per_px", "contact",
                         "truncated", "obstacle", "point_truth", "sigma_m", "lower_m",
                         "clear_to_m", "flagged"])
        for r in results:
            err = r.abs_error_m
            writer.writerow([r.frame, r.altitude_m, r.masks, r.method, r.section, r.status, r.kind,
                             "" if r.estimate_m is None else f"{r.estimate_m:.4f}",
                             "" if r.truth_m is None else f"{r.truth_m:.4f}",
                             "" if err is None else f"{err:.4f}", f"{r.gsd_m_per_px:.5f}",
                             int(r.contact), int(r.truncated), r.obstacle or "",
                             r.point_truth or "",
                             "" if r.sigma_m is None else f"{r.sigma_m:.4f}",
                             "" if r.lower_m is None else f"{r.lower_m:.4f}",
                             "" if r.clear_to_m is None else f"{r.clear_to_m:.4f}",
                             int(r.flagged)])


def read_csv(path: Path) -> list[SectionResult]:
    """The results of :func:`write_csv` again (to re-plot or re-summarise without measuring)."""
    def number(text: str) -> float | None:
        return float(text) if text else None

    with path.open(newline="") as f:
        return [SectionResult(row["frame"], float(row["altitude_m"]), row["masks"], row["method"],
                              int(row["section"]), row["status"], number(row["estimate_m"]),
                              number(row["truth_m"]), float(row["gsd_m_per_px"]),
                              bool(int(row["contact"])), bool(int(row["truncated"])),
                              row.get("obstacle") or None, row.get("point_truth") or None,
                              number(row.get("sigma_m", "")), number(row.get("lower_m", "")),
                              number(row.get("clear_to_m", "")),
                              bool(int(row.get("flagged") or 0)))
                for row in csv.DictReader(f)]


def _fmt(value: float | None, digits: int = 2) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _percent(share: float | None) -> str:
    return "—" if share is None else f"{100 * share:.0f} %"


def markdown_table(rows: list[AltitudeSummary]) -> str:
    lines = ["| masks | method | altitude m | n | MAE m (± std) | median m | median px | p95 m "
             "| > 1 m | missed | unseen | false | flagged | median sigma m | within 1 sigma "
             "| within 2 sigma | truth >= lower |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        share = "—" if r.over_1m_share is None else f"{100 * r.over_1m_share:.1f} %"
        mae = "—" if r.mae_m is None else f"{r.mae_m:.2f}" + (
            "" if r.std_m is None else f" ± {r.std_m:.2f}")
        lines.append(f"| {r.masks} | {r.method} | {r.altitude_m:.0f} | {r.n} | {mae} | "
                     f"{_fmt(r.median_m)} | {_fmt(r.median_px)} | {_fmt(r.p95_m)} | {share} | "
                     f"{r.missed} | {r.unseen} | {r.false} | {r.flagged} | "
                     f"{_fmt(r.median_sigma_m)} | "
                     f"{_percent(r.within_sigma_share)} | {_percent(r.within_2_sigma_share)} | "
                     f"{_percent(r.lower_bound_share)} |")
    return "\n".join(lines) + "\n"


def _finish(fig, ax, altitudes: list[float], ylabel: str, title: str, path: Path) -> Path:
    """Altitude ticks, labels, grid and legend; save the figure to ``path`` and close it."""
    import matplotlib.pyplot as plt

    ax.set_xticks(np.arange(len(altitudes)), [f"{a:.0f}" for a in altitudes])
    ax.set_xlabel("drone height above water (m)")
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_errors(results: list[SectionResult], rows: list[AltitudeSummary], out_dir: Path) -> list[Path]:
    """The paper's two figures: box plot of |error| per altitude, bar plot of MAE ± std;
    one box / bar per configuration at each altitude."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = sorted({(r.masks, r.method) for r in results})
    altitudes = sorted({r.altitude_m for r in results})
    width = 0.8 / max(1, len(configs))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    paths = []
    figsize = (min(14.0, max(8.0, 0.55 * len(altitudes) * max(1, len(configs)) ** 0.5)), 4.5)

    fig, ax = plt.subplots(figsize=figsize)
    for c, (masks, method) in enumerate(configs):
        data = [[r.abs_error_m for r in results if r.kind == "estimate" and r.masks == masks
                 and r.method == method and r.altitude_m == a] for a in altitudes]
        positions = np.arange(len(altitudes)) + (c - (len(configs) - 1) / 2) * width
        keep = [i for i, d in enumerate(data) if d]
        if not keep:
            continue
        bp = ax.boxplot([data[i] for i in keep], positions=positions[keep], widths=width * 0.85,
                        showfliers=True, patch_artist=True, flierprops={"markersize": 2})
        for patch in bp["boxes"]:
            patch.set_facecolor(colours[c % len(colours)])
            patch.set_alpha(0.6)
        ax.plot([], [], color=colours[c % len(colours)], lw=6, alpha=0.6, label=f"{masks}, {method}")
    ax.set_yscale("symlog", linthresh=0.1)
    paths.append(_finish(fig, ax, altitudes, "absolute distance error (m)",
                         "Absolute distance error per section", out_dir / "distance_error_box.png"))

    fig, ax = plt.subplots(figsize=figsize)
    for c, (masks, method) in enumerate(configs):
        sel = {r.altitude_m: r for r in rows if r.masks == masks and r.method == method}
        mae = [sel[a].mae_m if a in sel and sel[a].mae_m is not None else np.nan for a in altitudes]
        std = [sel[a].std_m if a in sel and sel[a].std_m is not None else np.nan for a in altitudes]
        positions = np.arange(len(altitudes)) + (c - (len(configs) - 1) / 2) * width
        below = np.minimum(std, mae)            # an absolute error is never below zero
        ax.bar(positions, mae, width * 0.9, yerr=[below, std], capsize=2,
               label=f"{masks}, {method}",
               color=colours[c % len(colours)], alpha=0.8)
    paths.append(_finish(fig, ax, altitudes, "mean absolute error (m), ± std",
                         "Mean absolute distance error", out_dir / "distance_mae_bar.png"))
    return paths


def worst_frames(results: list[SectionResult], masks_name: str, method: str, count: int
                 ) -> list[tuple[str, float]]:
    """The ``count`` frames of one configuration with the largest summed absolute error
    over their estimates, as ``(stem, summed error m)``, worst first."""
    totals: dict[str, float] = {}
    for r in results:
        if r.masks == masks_name and r.method == method and r.kind == "estimate":
            totals[r.frame] = totals.get(r.frame, 0.0) + r.abs_error_m
    return sorted(totals.items(), key=lambda kv: -kv[1])[:count]


def draw_error_panel(dataset: Path, frame: dict, masks: MaskSource, method: str,
                     title: str, clearance: ClearanceSettings | None = None) -> np.ndarray:
    """One frame measured again and drawn as three panels side by side: the overlay of the
    report (distances, obstacle points), the simulator's labels and the measured masks, both
    with the vessel's sections and the reported obstacle points, so a wrong distance can be
    traced to the pixels that caused it."""
    from harborsight.images import read_image
    from harborsight.viz.contact_sheet import colourise_labels
    from harborsight.viz.overlay import YELLOW, draw_banner, draw_overlay

    stem = Path(frame["image"]).stem
    meta = parse_frame_metadata(frame, dataset / "frames" / f"{stem}.json",
                                base_dir=dataset / "frames")
    image = read_image(dataset / "images" / frame["image"])
    measured, confidence = split_mask(masks(dataset, frame))
    report = measure_frame(measured, meta, load_vessel_spec(dataset / frame["vessel_spec"]),
                           dataclasses.replace(clearance or ClearanceSettings(), method=method),
                           mask_from_file=masks is oracle_masks, confidence=confidence)
    truth = [t["distance_m"] for t in frame["ground_truth"]["sections"]]
    truth_text = " ".join("-" if t is None else f"{t:.1f}" for t in truth)
    panels = [draw_overlay(image, report, footer=f"true m: {truth_text}")]
    for labels, name in ((oracle_masks(dataset, frame), "simulator labels"),
                         (measured, f"{title} masks")):
        panel = colourise_labels(labels)
        for s in report.sections:
            hull = np.asarray(s.hull_px, float)
            if np.isfinite(hull).all():
                cv2.line(panel, tuple(np.round(hull[0]).astype(int)),
                         tuple(np.round(hull[1]).astype(int)), (255, 255, 255), 1, cv2.LINE_AA)
            if s.obstacle_point_px:
                cv2.circle(panel, tuple(np.round(s.obstacle_point_px).astype(int)), 3, YELLOW, -1,
                           cv2.LINE_AA)
        draw_banner(panel, f"{stem}: {name}")
        panels.append(panel)
    return np.hstack(panels)


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


def write_outputs(results: list[SectionResult], out_dir: Path) -> dict:
    """CSV of every estimate, summary JSON and Markdown, the two plots, error_sources.json
    and .md when obstacle points were traced, and, when results carry obstacle kinds,
    by_obstacle.json and .md and error_budget.json and .md."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = summarise(results)
    write_csv(results, out_dir / "sections.csv")
    (out_dir / "summary.json").write_text(strict_json([asdict(r) for r in rows], indent=1) + "\n")
    (out_dir / "summary.md").write_text(markdown_table(rows))
    plots = plot_errors(results, rows, out_dir) if results else []
    by_obstacle = summarise_by_obstacle(results)
    if by_obstacle:
        (out_dir / "by_obstacle.json").write_text(
            strict_json([asdict(r) for r in by_obstacle], indent=1) + "\n")
        (out_dir / "by_obstacle.md").write_text(markdown_obstacle_table(by_obstacle))
    budget = summarise_error_budget(results)
    if budget:
        (out_dir / "error_budget.json").write_text(
            strict_json([asdict(r) for r in budget], indent=1) + "\n")
        (out_dir / "error_budget.md").write_text(markdown_error_budget_table(budget))
    sources = summarise_error_sources(results)
    if sources:
        (out_dir / "error_sources.json").write_text(
            strict_json([asdict(r) for r in sources], indent=1) + "\n")
        (out_dir / "error_sources.md").write_text(markdown_error_source_table(sources))
    return {"rows": rows, "plots": plots, "by_obstacle": by_obstacle, "error_sources": sources,
            "error_budget": budget}

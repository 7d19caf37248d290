"""Where the masks of a distance evaluation come from: the simulator's labels
(``oracle``), a segmentation model, or a flat world drawn from the scene's footprints (the
planar assumption's share of the error)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import HarborsightError
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

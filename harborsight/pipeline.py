"""Files in, reports and overlays out: one frame, or a folder where a bad frame is skipped.

A batch folder is either the dataset layout of ``docs/design.md`` (``frames/*.json``,
``images/``, ``labels/``) or a flat folder of frame JSONs next to their images, with masks
in ``--masks DIR`` (or ``labels/`` / ``masks/`` beside them). A frame without a mask (no mask
folder, or a segmentation model asked for) is segmented by a model: anything with
``segment(image_bgr) -> labels``, e.g. :class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter`.
A frame may name its vessel with a ``vessel_spec`` key (path relative to the dataset root);
``--vessel`` overrides it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from glob import escape as glob_escape
from pathlib import Path
from typing import NamedTuple, Protocol

import cv2
import numpy as np

from harborsight.clearance.measure import ClearanceSettings, measure_frame
from harborsight.clearance.report import ClearanceReport
from harborsight.errors import HarborsightError, InputError, brief
from harborsight.files import is_existing_file, natural_key
from harborsight.frame import FrameMetadata, load_frame_metadata
from harborsight.geometry.camera import CameraIntrinsics
from harborsight.geometry.gsd import nadir_gsd_m_per_px
from harborsight.geometry.rotations import world_from_camera_rotation
from harborsight.images import read_image_and_no_data, read_mask
from harborsight.perception.classes import IGNORE
from harborsight.perception.confidence import SolidConfidence
from harborsight.vessel.spec import VesselSpec, load_vessel_spec
from harborsight.viz.overlay import draw_overlay


class Segmenter(Protocol):
    """A model: ``segment(image) -> labels``; one that also has ``segment_with_confidence(image)
    -> (labels, SolidConfidence)`` (as :class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter`)
    gives its probabilities to the distances' uncertainty."""

    path: Path

    def segment(self, image_bgr: np.ndarray) -> np.ndarray: ...


class FrameMask(NamedTuple):
    """A frame's class labels, where they came from, and the model's probabilities behind
    them (None for a mask file, or a model that does not give them)."""

    labels: np.ndarray
    source: str
    from_file: bool
    confidence: SolidConfidence | None = None


@dataclass(frozen=True)
class FrameJob:
    stem: str
    meta_path: Path
    image_path: Path | None = None
    mask_path: Path | None = None          # None: segment the image with a model


@dataclass
class FrameOutcome:
    job: FrameJob
    report: ClearanceReport | None = None
    meta: FrameMetadata | None = None
    error: str | None = None
    report_path: Path | None = None
    overlay_path: Path | None = None


def _find_vessel_spec(meta: FrameMetadata, meta_path: Path) -> Path:
    ref = meta.extra.get("vessel_spec")
    if not ref:
        raise InputError(meta_path, "vessel_spec", "no --vessel given and the frame names none")
    if not isinstance(ref, str):
        raise InputError(meta_path, "vessel_spec", f"expected a vessel.yaml path, got {ref!r}")
    for base in (meta_path.parent, meta_path.parent.parent):
        if is_existing_file(base / ref):
            return base / ref
    raise InputError(meta_path, "vessel_spec", f"file not found: {brief(ref)}")


class VesselCache:
    """Loads each vessel.yaml once per batch; ``on_notes`` hears each spec's notes
    (:attr:`VesselSpec.notes`) once, when it is first loaded, with its path."""

    def __init__(self, fixed: VesselSpec | None = None,
                 on_notes: Callable[[str, tuple[str, ...]], None] | None = None) -> None:
        self.fixed = fixed
        self.on_notes = on_notes
        self._specs: dict[Path, VesselSpec] = {}
        if fixed is not None and fixed.notes and on_notes is not None:
            on_notes(fixed.source or fixed.name, fixed.notes)

    def for_frame(self, meta: FrameMetadata, meta_path: Path) -> VesselSpec:
        if self.fixed is not None:
            return self.fixed
        path = _find_vessel_spec(meta, meta_path).resolve()
        if path not in self._specs:
            self._specs[path] = spec = load_vessel_spec(path)
            if spec.notes and self.on_notes is not None:
                self.on_notes(str(path), spec.notes)
        return self._specs[path]


def check_image_size(image: np.ndarray, meta: FrameMetadata, source: str | Path) -> None:
    """The image must have the size the frame's camera says."""
    if image.shape[:2] != (meta.camera.height, meta.camera.width):
        raise InputError(
            source, "camera.width" if image.shape[1] != meta.camera.width else "camera.height",
            f"image is {image.shape[1]}x{image.shape[0]} but the camera is "
            f"{meta.camera.width}x{meta.camera.height}",
        )


def frame_labels(image: np.ndarray, mask_path: Path | None, segmenter: Segmenter | None,
                 source: str | Path, no_data: np.ndarray | None = None,
                 meta: FrameMetadata | None = None) -> FrameMask:
    """The frame's class mask and where it came from: the mask file, else the model. Pixels
    in ``no_data`` (bool (H, W): no picture there, :func:`~harborsight.images.read_image_and_no_data`)
    are labelled 255, ignore, which measuring counts as solid: a transparent corner is
    not seen water. ``meta``: the frame's metadata, whose GSD (:func:`frame_gsd_m_per_px`) a
    segmenter that takes one is given (:class:`~harborsight.perception.gsd_scaling.GsdScaledSegmenter`)."""
    mask = _frame_labels(image, mask_path, segmenter, source, meta)
    if no_data is None or not no_data.any():
        return mask
    if mask.labels.shape != no_data.shape:
        raise InputError(source, "mask", f"mask is {mask.labels.shape[1]}x{mask.labels.shape[0]} "
                         f"but the image is {no_data.shape[1]}x{no_data.shape[0]}")
    return mask._replace(labels=unseen_where_no_picture(mask.labels, mask.confidence, no_data))


def unseen_where_no_picture(labels: np.ndarray, confidence: SolidConfidence | None,
                            no_data: np.ndarray) -> np.ndarray:
    """``labels`` with the pixels of ``no_data`` set to 255 (ignore: solid when measuring),
    and ``confidence`` told they are solid."""
    labels = labels.copy()
    labels[no_data] = IGNORE
    if confidence is not None:
        confidence.no_picture = no_data
    return labels


#: the optical axis's cosine off straight down below which a view's centre footprint is not
#: used (78 degrees: near the horizon it grows without bound)
MIN_AXIS_COSINE = 0.2


def frame_gsd_m_per_px(meta: FrameMetadata) -> float:
    """The ground sample distance at the image centre on the water, metres per pixel: the
    centre pixel's footprint along the tilt, ``h / (f · cos²θ)`` with ``h`` the height above
    the water, ``f = min(fx, fy)`` and ``θ`` the optical axis's angle off straight down
    (``h / f`` at nadir; ``cos θ`` at least :data:`MIN_AXIS_COSINE`)."""
    rotation = world_from_camera_rotation(math.radians(meta.yaw_deg), math.radians(meta.pitch_deg),
                                          math.radians(meta.roll_deg))
    axis_cosine = max(-float(rotation[2, 2]), MIN_AXIS_COSINE)   # (R · (0, 0, 1)) · down
    return (nadir_gsd_m_per_px(meta.height_above_water_m, meta.camera.fx, meta.camera.fy)
            / axis_cosine ** 2)


def _frame_labels(image: np.ndarray, mask_path: Path | None, segmenter: Segmenter | None,
                  source: str | Path, meta: FrameMetadata | None = None) -> FrameMask:
    if mask_path is not None:
        return FrameMask(read_mask(mask_path), str(mask_path), from_file=True)
    if segmenter is not None:
        if getattr(segmenter, "takes_gsd", False):
            gsd_m_per_px = None if meta is None else frame_gsd_m_per_px(meta)
            labels, confidence = segmenter.segment_with_confidence(image, gsd_m_per_px)
            return FrameMask(labels, str(segmenter.path), False, confidence)
        if hasattr(segmenter, "segment_with_confidence"):
            labels, confidence = segmenter.segment_with_confidence(image)
            return FrameMask(labels, str(segmenter.path), False, confidence)
        return FrameMask(segmenter.segment(image), str(segmenter.path), from_file=False)
    raise InputError(source, "mask", "no mask given and no segmentation model")


def measure_mask(mask: FrameMask, meta: FrameMetadata, vessel: VesselSpec,
                 settings: ClearanceSettings) -> ClearanceReport:
    """:func:`~harborsight.clearance.measure.measure_frame` of a :class:`FrameMask`."""
    return measure_frame(mask.labels, meta, vessel, settings, mask_source=mask.source,
                         mask_from_file=mask.from_file, confidence=mask.confidence)


def frame_image_path(job: FrameJob, meta: FrameMetadata) -> Path:
    """The image of a job: the file named like its JSON, else the one its ``image`` key
    names (in ``images/``, beside the JSON or in the root); where there is none, a folder
    that stands in one of those places under the image's name (reported as a folder), else
    the path beside the JSON (reported as not found)."""
    if job.image_path is not None:
        return job.image_path
    found = find_frame_image(job.meta_path, meta.image)
    if found is not None:
        return found
    names = [meta.image] + [job.meta_path.stem + ext for ext in IMAGE_EXTENSIONS]
    for folder in image_folders(job.meta_path):
        for name in names:
            if (folder / name).is_dir():
                return folder / name
    return job.meta_path.parent / meta.image


def measure_job(
    job: FrameJob, vessels: VesselCache, settings: ClearanceSettings, out_dir: Path | None,
    camera: CameraIntrinsics | None = None, overlay: bool = True,
    segmenter: Segmenter | None = None,
) -> FrameOutcome:
    """Measure one frame from files, its labels from its mask or, without one, from
    ``segmenter``; raises :class:`InputError` on bad input."""
    meta = load_frame_metadata(job.meta_path, camera=camera)
    image_path = frame_image_path(job, meta)
    image, no_data = read_image_and_no_data(image_path, camera_pixels=True)
    check_image_size(image, meta, image_path)
    mask = frame_labels(image, job.mask_path, segmenter, job.meta_path, no_data, meta)
    report = measure_mask(mask, meta, vessels.for_frame(meta, job.meta_path), settings)
    outcome = FrameOutcome(job, report, meta)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        stem = job.stem          # the JSON's name: unique in a folder, and what masks go by
        outcome.report_path = out_dir / f"{stem}.json"
        report.write(outcome.report_path)
        if overlay:
            outcome.overlay_path = out_dir / f"{stem}.png"
            cv2.imwrite(str(outcome.overlay_path), draw_overlay(image, report))
    return outcome


IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def image_folders(meta_path: Path) -> list[Path]:
    """Where a frame JSON's image may be: ``images/`` of the dataset, beside the JSON, and
    the dataset root (the JSON's folder's parent when the JSON is in ``frames/``)."""
    root = meta_path.parent.parent if meta_path.parent.name == "frames" else meta_path.parent
    return list(dict.fromkeys([root / "images", meta_path.parent, root]))


def find_frame_image(meta_path: Path, image_name: str | None = None) -> Path | None:
    """The frame's image: the file its ``image`` key names, else one named like the JSON,
    with any of :data:`IMAGE_EXTENSIONS` in any letter case (DJI writes ``.JPG``)."""
    folders = [d for d in image_folders(meta_path) if d.is_dir()]
    if image_name:
        for folder in folders:
            if (folder / image_name).is_file():
                return folder / image_name
    for folder in folders:
        for candidate in sorted(folder.glob(f"{glob_escape(meta_path.stem)}.*")):
            if candidate.suffix.lower() in IMAGE_EXTENSIONS and candidate.is_file():
                return candidate
    return None


def discover_jobs(folder: Path, masks_dir: Path | None = None, segment: bool = False
                  ) -> list[FrameJob]:
    """Frames of a batch folder in natural order of their names, each with its image and
    mask paths (module docstring). The mask path is ``None`` (segment with a model) for
    every frame when ``segment``, and when there is neither ``masks_dir`` nor a ``labels/``
    or ``masks/`` folder."""
    frames_dir = folder / "frames" if (folder / "frames").is_dir() else folder
    meta_paths = sorted(frames_dir.glob("*.json"), key=lambda p: natural_key(p.name))
    if not meta_paths:
        raise InputError(folder, None, "no frame JSON files found (expected frames/*.json or *.json)")
    mask_dirs = [masks_dir] if masks_dir else [d for d in (folder / "labels", folder / "masks")
                                               if d.is_dir()]
    if segment:
        mask_dirs = []
    jobs = []
    for meta_path in meta_paths:
        stem = meta_path.stem
        image = find_frame_image(meta_path)
        mask = next((d / f"{stem}.png" for d in mask_dirs if (d / f"{stem}.png").is_file()),
                    mask_dirs[0] / f"{stem}.png" if mask_dirs else None)
        jobs.append(FrameJob(stem, meta_path, image, mask))
    return jobs


def run_batch(
    jobs: Iterable[FrameJob], vessels: VesselCache, settings: ClearanceSettings, out_dir: Path,
    camera: CameraIntrinsics | None = None, on_done: Callable[[FrameOutcome], None] | None = None,
    segmenter: Segmenter | None = None,
) -> list[FrameOutcome]:
    """Measure every job; a bad frame is recorded with its reason and the rest go on."""
    outcomes = []
    for job in jobs:
        try:
            outcome = measure_job(job, vessels, settings, out_dir, camera, segmenter=segmenter)
        except HarborsightError as exc:
            outcome = FrameOutcome(job, error=str(exc))
        except Exception as exc:  # one bad frame must not end the batch
            outcome = FrameOutcome(job, error=f"{job.meta_path}: unexpected "
                                              f"{type(exc).__name__}: {exc}")
        outcomes.append(outcome)
        if on_done:
            on_done(outcome)
    return outcomes

"""The ``harborsight`` app, its consoles, and what several command modules share (options'
defaults, settings, the segmenter, numeric and size parsing)."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.console import Console

from harborsight.errors import InputError

if TYPE_CHECKING:  # imported by the commands that use them: the CLI starts faster
    from harborsight.clearance.measure import ClearanceSettings


#: Bounds of frame counts and rates (telemetry video, run): ten hours at 240 frames per second.
MAX_VIDEO_FRAMES = 10_000_000


MAX_VIDEO_FPS = 1000.0
#: Upper bound of --pose-margin-px and --own-rim-px: a morphological growth of this many
#: pixels is already a third of a 640x360 frame (and 10,000 px would take minutes and GBs).
MAX_MARGIN_PX = 100
#: Upper bound of --threads.
MAX_THREADS = 1024


app = typer.Typer(
    rich_markup_mode=None,  # help as written: "[test]" is a default, not a Rich tag
    add_completion=False, no_args_is_help=True,
    help="Per-section hull clearance of a vessel, measured from a companion drone's camera.",
)


console = Console()


err_console = Console(stderr=True, soft_wrap=True)


class Method(StrEnum):
    ground_plane = "ground_plane"
    gsd = "gsd"


def fmt_number(value: float | None, digits: int) -> str:
    """A number to ``digits`` decimals; "—" for None or NaN (a class absent from a split)."""
    return "—" if value is None or value != value else f"{value:.{digits}f}"


def vessel_cache(vessel: Path | None):
    """A :class:`~harborsight.pipeline.VesselCache` for ``--vessel`` (or the frames' own
    specs) that says each spec's notes once, as ``note: FILE: ...`` on standard error."""
    from harborsight.pipeline import VesselCache
    from harborsight.vessel.spec import load_vessel_spec

    def say(source: str, notes: tuple[str, ...]) -> None:
        for note in notes:
            err_console.print(f"note: {source}: {note}", markup=False, highlight=False)

    return VesselCache(load_vessel_spec(vessel) if vessel else None, on_notes=say)


def check_masks_folder(masks: Path | None) -> None:
    """One error for a --masks folder that is not there, rather than one per frame."""
    if masks is not None and not masks.is_dir():
        raise InputError(masks, "--masks", "not a folder" if masks.exists() else "no such folder")


def clearance_settings(method: Method, sections: int | None, section_length_m: float | None,
              pose_margin_px: float, own_rim_px: int, refine_pose: bool = True,
              sigma: list[str] | None = None, own_motion: bool = True) -> ClearanceSettings:
    from harborsight.clearance.measure import ClearanceSettings
    from harborsight.clearance.pose_refinement import PoseRefinementSettings

    if sections is not None and section_length_m is not None:
        raise InputError(None, "--section-length-m", "give either --sections or "
                         "--section-length-m, not both")
    return ClearanceSettings(method=method.value, pose_margin_px=pose_margin_px,
                             own_rim_px=own_rim_px, n_sections=sections,
                             section_length_m=section_length_m,
                             pose_refinement=PoseRefinementSettings(enabled=refine_pose),
                             sigma_options=parse_sigma_options(sigma), own_motion=own_motion)


def parse_sigma_options(values: list[str] | None) -> tuple[tuple[str, float], ...]:
    """The ``--sigma NAME=VALUE`` options, checked (the last of a name wins)."""
    from harborsight.geometry.sensor_sigmas import parse_sigma_option

    chosen: dict[str, float] = {}
    for text in values or []:
        try:
            name, value = parse_sigma_option(text)
        except ValueError as exc:
            raise InputError(None, "--sigma", str(exc)) from None
        chosen[name] = value
    return tuple(chosen.items())


#: help of --sigma, shared by measure, run and evaluate distance
SIGMA_HELP = ("One sigma of a sensor's error, for frames whose metadata does not carry its own "
              "(repeatable): uav_gps and vessel_gps (horizontal RMS, m, or rtk / dgps / "
              "standalone), vessel_heading_deg (or magnetic / gnss / gyro), camera_yaw_deg, "
              "camera_tilt_deg, height_m, water_level_m, focal_rel (the focal length, "
              "relative), clock_s, edge_px, edge_m. Defaults: "
              "standalone GPS, 2 deg compasses, 0.5 deg tilt, 1 m height, 0.3 m water level, "
              "0.005 focal length (a calibration; 0.01-0.02 for a datasheet's), "
              "0.05 s clock, a model's edge 4 px and 0.5 m in quadrature (1 px and 0 m for mask "
              "files). Each ok section then "
              "carries sigma_m and distance_lower_m.")


#: defaults of --pose-margin-px and --own-rim-px: ClearanceSettings.pose_margin_px and
#: .own_rim_px (kept here: the CLI starts without importing the measurement code)
POSE_MARGIN_PX = 2.0


OWN_RIM_PX = 4


def print_pose_refinement_summary(refinements: list) -> None:
    """The batch's one line on pose refinement: on stdout, or on stderr when some frames
    kept the sensors' pose because the alignment was not trusted."""
    from harborsight.clearance.refinement_summary import refinement_summary

    line = refinement_summary(refinements)
    if line:
        (err_console if "kept" in line else console).print(line, markup=False, highlight=False)


#: help of --refine-pose/--no-refine-pose, shared by measure, run and evaluate distance
REFINE_POSE_HELP = ("Align the projected vessel to its own ship pixels (a correction of its "
                    "position and heading for GPS and compass error) and measure with that pose "
                    "when the fit is trustworthy; each report says what was found "
                    "(pose_refinement).")


#: help of --own-motion/--no-own-motion, shared by measure, run and live
OWN_MOTION_HELP = ("Where a frame gives the vessel's ground velocity (vessel.velocity_en_mps, and "
                   "its rate of turn), take the rate at which the vessel's own motion closes "
                   "each section's gap as part of its closing speed (own_closing_mps in the "
                   "report): the tracker then follows the vessel's stops and starts at once and "
                   "measures only the obstacle's own motion from the image.")


#: help of --own-rim-px, shared by measure, run and evaluate distance
OWN_RIM_HELP = ("Ship-class slivers up to this many pixels thick hugging the vessel's own "
                 "region count as the vessel (a segmenter draws the vessel a few pixels too "
                 "wide, onto its shadow); thicker neighbours are kept whole. 0: off.")


#: help of --exact-int8 (segment, evaluate segmentation)
EXACT_INT8_HELP = ("Run an int8 model's graph as written (dequantise, float convolution, "
                   "quantise) instead of ONNX Runtime's fused integer kernels, at 1.3-2.2x the "
                   "time. The fused kernels' labels differ from it where two classes nearly "
                   "tie (0.1-0.5 % of the default model's pixels on average over our real "
                   "frames, up to 1.8 % in a frame); on x86 CPUs without VNNI, whose uint8 x "
                   "int8 sums saturate, the weights run as uint8 (docs/results.md).")


#: help of --flips (segment, evaluate segmentation and distance, measure, run)
FLIPS_HELP = ("Test-time flips: 1, the frame alone; 2, also its mirror image; 4, also both upside "
              "down (nadir views; an oblique view with a horizon: 2). The class probabilities of "
              "the copies, flipped back, are averaged: more time for better masks (the default "
              "model on real val frames: +0.6 to +1.5 points mIoU with 4, at 4x the time; "
              "docs/results.md).")


#: help of --segment-gsd-m (run, measure, evaluate distance, live)
SEGMENT_GSD_HELP = ("Show the model each frame at this ground sample distance (m per pixel on "
                    "the water, from the frame's height and focal length) or finer: a coarser "
                    "frame is enlarged to it (its longer side to at most 3 model inputs), "
                    "segmented in overlapping windows of the model input and mixed with the "
                    "frame seen whole, 2-17 model calls a frame instead of one. 0: off, every "
                    "frame stretched into one model input. The default model draws edges to "
                    "about 2-5 of its pixels, so metres of error grow with the GSD it sees "
                    "(docs/results.md, 'Segmenting at a chosen GSD').")


def load_segmenter(model: Path | None, reference_arithmetic: bool = False, flips: int = 1,
                   segment_gsd_m: float | None = None):
    """The ONNX model at ``model``, or the packaged default model (clear error if absent);
    with ``flips`` > 1 one whose ``segment`` and ``segment_with_confidence`` use them
    (:class:`~harborsight.perception.flips.FlippedSegmenter`, for the pipelines); with
    ``segment_gsd_m`` one that sees each frame at that GSD or finer
    (:class:`~harborsight.perception.gsd_scaling.GsdScaledSegmenter`)."""
    from harborsight.perception.default_model import describe, load_default_segmenter
    from harborsight.perception.flips import flip_views
    from harborsight.perception.gsd_scaling import check_segment_gsd, pipeline_segmenter

    flip_views(flips)
    segment_gsd_m = check_segment_gsd(segment_gsd_m)
    segmenter = load_default_segmenter(model, reference_arithmetic)
    console.print(f"segmenting with {describe(segmenter)}"
                  + (f", {flips} flipped copies a frame" if flips != 1 else "")
                  + (f", frames coarser than {segment_gsd_m:g} m/px enlarged to it"
                     if segment_gsd_m else ""), markup=False)
    return pipeline_segmenter(segmenter, flips, segment_gsd_m)


def need_torch() -> None:
    try:
        import torch  # noqa: F401
    except ImportError as exc:
        err_console.print(f"error: training needs torch (pip install -e '.[train]'): {exc}")
        raise typer.Exit(2) from None


def split_names(text: str) -> list[str]:
    """The names of a comma-separated option (``stem, stage1,stage2``), blanks dropped."""
    return [name.strip() for name in text.split(",") if name.strip()]


def parse_crop(text: str, option: str = "crop") -> tuple[int, int]:
    """``HxW`` (rows x columns) or ``N`` for a square size."""
    try:
        parts = [int(p) for p in text.lower().split("x")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts *= 2
    if len(parts) != 2 or min(parts) < 1:
        raise InputError(None, option, f"expected HEIGHTxWIDTH or N, got {text!r}")
    return parts[0], parts[1]


def main() -> None:
    try:
        app()
    except InputError as exc:  # pragma: no cover - commands catch their own
        err_console.print(f"error: {exc}", markup=False)
        raise SystemExit(2) from None

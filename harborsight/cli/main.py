"""The ``harborsight`` app and its original commands (measure, run, demo, simulate, train,
evaluate, export, telemetry, ...): thin wrappers over the library."""

from __future__ import annotations

import json
import re
import shlex
from collections import Counter
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import cv2
import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from harborsight.errors import HarborsightError, InputError
from harborsight.files import strict_json, write_image
from harborsight.perception.segment_images import SegmentMode

if TYPE_CHECKING:  # the commands import what they use: `simulate` starts faster
    from harborsight.clearance.measure import ClearanceSettings
    from harborsight.pipeline import FrameOutcome, VesselCache

#: Bounds of frame counts and rates (telemetry video, run): ten hours at 240 frames per second.
MAX_VIDEO_FRAMES = 10_000_000
MAX_VIDEO_FPS = 1000.0

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


def _fmt(value: float | None, digits: int) -> str:
    """A number to ``digits`` decimals; "—" for None or NaN (a class absent from a split)."""
    return "—" if value is None or value != value else f"{value:.{digits}f}"


def print_report_table(outcome: FrameOutcome) -> None:
    """Per-section table; adds the ground truth column when the frame carries one."""
    from harborsight.clearance.report import STATUS_OK

    report = outcome.report
    truth = {}
    gt = outcome.meta.extra.get("ground_truth") if outcome.meta else None
    if gt and gt.get("n_sections") == len(report.sections):
        truth = {s["index"]: s.get("distance_m") for s in gt["sections"]}
    title = (f"{report.image}: {report.vessel}, {report.altitude_m:.0f} m above water, "
             f"{report.method}, GSD {report.gsd_m_per_px * 100:.1f} cm/px")
    table = Table(title=title, title_justify="left")
    table.add_column("section", justify="right")
    table.add_column("status")
    table.add_column("distance m", justify="right")
    table.add_column("pixels", justify="right")
    if truth:
        table.add_column("truth m", justify="right")
        table.add_column("error px", justify="right")
    table.add_column("notes")
    for s in report.sections:
        notes = ", ".join(n for n, on in (("contact", s.contact), ("cut by frame", s.truncated)) if on)
        style = "bold red" if s.status == STATUS_OK and s.distance_m < 2 else None
        row = [str(s.index), s.status, _fmt(s.distance_m, 2), _fmt(s.distance_px, 1)]
        if truth:
            t = truth.get(s.index)
            err = (None if s.distance_m is None or t is None
                   else (s.distance_m - t) / report.gsd_m_per_px)
            row += [_fmt(t, 2), _fmt(err, 2)]
        table.add_row(*row, notes, style=style)
    console.print(table)
    md = report.min_distance_m
    console.print(f"closest: section {report.closest_section} at {_fmt(md, 2)} m"
                  if md is not None else "no obstacle in view")


def _check_masks_folder(masks: Path | None) -> None:
    """One error for a --masks folder that is not there, rather than one per frame."""
    if masks is not None and not masks.is_dir():
        raise InputError(masks, "--masks", "not a folder" if masks.exists() else "no such folder")


def _settings(method: Method, sections: int | None, section_length_m: float | None,
              pose_margin_px: float, own_rim_px: int) -> ClearanceSettings:
    from harborsight.clearance.measure import ClearanceSettings

    if sections is not None and section_length_m is not None:
        raise InputError(None, "--section-length-m", "give either --sections or "
                         "--section-length-m, not both")
    return ClearanceSettings(method=method.value, pose_margin_px=pose_margin_px,
                             own_rim_px=own_rim_px, n_sections=sections,
                             section_length_m=section_length_m)


#: defaults of --pose-margin-px and --own-rim-px: ClearanceSettings.pose_margin_px and
#: .own_rim_px (kept here: the CLI starts without importing the measurement code)
POSE_MARGIN_PX = 2.0
OWN_RIM_PX = 4

#: help of --own-rim-px, shared by measure, run and evaluate distance
_OWN_RIM_HELP = ("Ship-class slivers up to this many pixels thick hugging the vessel's own "
                 "region count as the vessel (a segmenter draws the vessel a few pixels too "
                 "wide, onto its shadow); thicker neighbours are kept whole. 0: off.")


def _segmenter(model: Path | None):
    """The ONNX model at ``model``, or the packaged default model (clear error if absent)."""
    from harborsight.perception.default_model import describe, load_default_segmenter

    segmenter = load_default_segmenter(model)
    console.print(f"segmenting with {describe(segmenter)}", markup=False)
    return segmenter


def _run_folder(folder: Path, masks: Path | None, vessels: VesselCache,
                settings: ClearanceSettings, out: Path, camera, show_tables: bool,
                model: Path | None = None, strict: bool = False) -> int:
    """Measure a folder; exit code 1 if every frame failed (``strict``: if any did)."""
    from harborsight.pipeline import discover_jobs, run_batch

    jobs = discover_jobs(folder, masks, segment=model is not None)
    segmenter = _segmenter(model) if any(job.mask_path is None for job in jobs) else None
    with Progress(TextColumn("[bold]measuring"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True) as progress:
        task = progress.add_task("frames", total=len(jobs))
        outcomes = run_batch(jobs, vessels, settings, out, camera,
                             on_done=lambda _: progress.advance(task), segmenter=segmenter)
    good = [o for o in outcomes if o.error is None]
    bad = [o for o in outcomes if o.error is not None]
    if show_tables:
        for outcome in good:
            print_report_table(outcome)
    console.print(f"[green]{len(good)} frame(s) measured[/]; reports and overlays in {escape(str(out))}/")
    if bad:
        err_console.print(f"[red]{len(bad)} frame(s) skipped:[/]")
        for outcome in bad:
            err_console.print(f"  {outcome.job.stem}: {outcome.error}", markup=False)
    return 1 if bad and (strict or not good) else 0


@app.command()
def measure(
    input_path: Annotated[Path, typer.Argument(
        metavar="INPUT", help="An image, or a folder of frames (frames/*.json + images/ + labels/, "
        "or frame JSONs beside their images).")],
    meta: Annotated[Path | None, typer.Option(
        help="Frame metadata (harborsight.frame/1 JSON) of a single image. "
        "Default: the image's name with .json.")] = None,
    vessel: Annotated[Path | None, typer.Option(
        help="Vessel spec (vessel.yaml). Default for folders: each frame's vessel_spec key.")] = None,
    mask: Annotated[Path | None, typer.Option(
        help="Label mask of a single image (PNG: 0 water, 1 ship, 2 obstacle, 255 ignore).")] = None,
    masks: Annotated[Path | None, typer.Option(
        help="Folder of masks named like the frames (folders only; default labels/ or masks/).")] = None,
    model: Annotated[Path | None, typer.Option(
        help="ONNX segmentation model (harborsight export) that labels the frames instead of "
        "masks. Without it, frames are labelled by the packaged default model when no mask is "
        "given (no --mask/--masks, no labels/ or masks/ folder); in a folder with masks, a "
        "frame whose mask is missing is reported and skipped.")] = None,
    out: Annotated[Path, typer.Option(help="Where reports (JSON) and overlays (PNG) go, named "
                                           "like the frame JSONs.")] = Path("out/measure"),
    method: Annotated[Method, typer.Option(
        help="ground_plane: back-project onto the water plane with the full pose (exact for "
        "any tilt); gsd: the paper's nadir GSD times pixel distances.")] = Method.ground_plane,
    sections: Annotated[int | None, typer.Option(
        min=1, help="Number of hull sections (overrides the vessel spec).")] = None,
    section_length_m: Annotated[float | None, typer.Option(
        min=0.1, help="Section length in metres (overrides the vessel spec).")] = None,
    camera: Annotated[Path | None, typer.Option(
        help="Camera calibration (OpenCV FileStorage YAML/XML or ROS camera_info YAML) "
        "that replaces the frames' intrinsics.")] = None,
    pose_margin_px: Annotated[float, typer.Option(
        min=0.0, help="Growth in pixels of the vessel's own image region, for pose and mask "
        "error.")] = POSE_MARGIN_PX,
    own_rim_px: Annotated[int, typer.Option(min=0, help=_OWN_RIM_HELP)] = OWN_RIM_PX,
    tables: Annotated[bool, typer.Option(help="Print a table per frame.")] = True,
) -> None:
    """Measure hull clearance per section and write a report and an overlay per frame."""
    from harborsight.geometry.camera import load_camera_calibration
    from harborsight.pipeline import FrameJob, VesselCache, measure_job
    from harborsight.vessel.spec import load_vessel_spec

    try:
        if model is not None and (mask is not None or masks is not None):
            raise InputError(model, "model", "give either --model or --mask/--masks, not both")
        settings = _settings(method, sections, section_length_m, pose_margin_px, own_rim_px)
        intrinsics = load_camera_calibration(camera) if camera else None
        vessels = VesselCache(load_vessel_spec(vessel) if vessel else None)
        if input_path.is_dir():
            for name, given in (("--meta", meta), ("--mask", mask)):
                if given is not None:
                    raise InputError(given, name, f"{name} is for a single image; a folder's "
                                     "frames carry their own JSON files (and masks: --masks)")
            _check_masks_folder(masks)
            raise typer.Exit(_run_folder(input_path, masks, vessels, settings, out, intrinsics,
                                         tables, model))
        if masks is not None:
            raise InputError(masks, "--masks", "--masks is for folders; give a single image's "
                             "mask with --mask")
        meta_path = meta or input_path.with_suffix(".json")
        job = FrameJob(input_path.stem, meta_path, input_path, mask)
        segmenter = _segmenter(model) if mask is None else None
        outcome = measure_job(job, vessels, settings, out, intrinsics, segmenter=segmenter)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    if tables:
        print_report_table(outcome)
    console.print(f"report: {outcome.report_path}\noverlay: {outcome.overlay_path}",
                  markup=False, highlight=False)


def _run_flight_with_progress(source, out: Path, vessels, segmenter, options, inputs: dict):
    """:func:`harborsight.flight.run_flight` over ``source`` (a Folder- or VideoSource) with a
    progress bar that flags skipped frames."""
    from harborsight.flight import run_flight

    with Progress(TextColumn("[bold]run"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TextColumn("{task.fields[status]}"),
                  console=console, transient=True) as progress:
        task = progress.add_task("frames", total=source.frame_count or None, status="")

        from harborsight.flight.sources import NO_METADATA

        def advance(frame) -> None:
            if frame.is_frame:          # not a metadata line without a picture
                skipped = frame.error not in (None, NO_METADATA)
                progress.update(task, advance=1, status="[red]skipped one" if skipped else "")

        return run_flight(source.frames(), out, vessels, segmenter, options,
                          source_fps=source.fps, inputs=inputs, on_frame=advance)


@app.command("run")
def run_command(
    input_path: Annotated[Path, typer.Argument(
        metavar="INPUT", help="A folder of frames (frames/*.json + images/, or frame JSONs "
        "beside their images), or a video file with --metadata.")],
    metadata: Annotated[Path | None, typer.Option(
        help="Video only: JSON lines, one harborsight.frame/1 object per frame (a "
        "frame_index key names the video frame; without it, line n is frame n).")] = None,
    model: Annotated[Path | None, typer.Option(
        help="ONNX segmentation model (harborsight export). Default: the packaged model.")] = None,
    masks: Annotated[Path | None, typer.Option(
        help="Folders only: label masks named like the frames, used instead of a model "
        "(e.g. a simulator dataset's labels/ for oracle runs).")] = None,
    vessel: Annotated[Path | None, typer.Option(
        help="Vessel spec (vessel.yaml). Default: each frame's vessel_spec key.")] = None,
    out: Annotated[Path, typer.Option(
        help="Where reports/, overlays/, annotated.mp4, sections.csv, timeline.png and "
        "run.json go.")] = Path("out/run"),
    method: Annotated[Method, typer.Option(help="Distance method.")] = Method.ground_plane,
    sections: Annotated[int | None, typer.Option(
        min=1, help="Number of hull sections (overrides the vessel spec).")] = None,
    section_length_m: Annotated[float | None, typer.Option(
        min=0.1, help="Section length in metres (overrides the vessel spec).")] = None,
    camera: Annotated[Path | None, typer.Option(
        help="Camera calibration (OpenCV YAML/XML or ROS camera_info) replacing the frames' "
        "intrinsics.")] = None,
    pose_margin_px: Annotated[float, typer.Option(
        min=0.0, help="Growth in pixels of the vessel's own image region.")] = POSE_MARGIN_PX,
    own_rim_px: Annotated[int, typer.Option(min=0, help=_OWN_RIM_HELP)] = OWN_RIM_PX,
    overlays: Annotated[bool, typer.Option(help="Write an annotated PNG per frame.")] = True,
    video: Annotated[bool, typer.Option(help="Write annotated.mp4.")] = True,
    fps: Annotated[float | None, typer.Option(
        min=0.1, max=MAX_VIDEO_FPS, help="Frame rate of annotated.mp4. Default: the input "
        "video's, else from the frames' timestamps, else 5.")] = None,
    window_s: Annotated[float, typer.Option(
        min=0.1, max=3600.0, help="Closing speed: least-squares fit over this many seconds.")
    ] = 2.0,
) -> None:
    """Measure a whole flight: every frame segmented, measured and annotated; distances and
    closing speeds per section over time. A bad frame is reported and skipped."""
    from harborsight.flight import FolderSource, RunOptions, VideoSource
    from harborsight.geometry.camera import load_camera_calibration
    from harborsight.pipeline import VesselCache
    from harborsight.vessel.spec import load_vessel_spec

    try:
        if not input_path.exists():
            raise InputError(input_path, None, "not found (give a folder of frames, or a video "
                             "with --metadata)")
        intrinsics = load_camera_calibration(camera) if camera else None
        if input_path.is_dir():
            if metadata is not None:
                raise InputError(metadata, None, "--metadata is for videos; a folder's frames "
                                 "carry their own JSON files")
            if model is not None and masks is not None:
                raise InputError(model, "model", "give either --model or --masks, not both")
            _check_masks_folder(masks)
            source = FolderSource(input_path, masks, use_masks=masks is not None,
                                  camera=intrinsics)
            segmenter = None if masks is not None else _segmenter(model)
        else:
            if metadata is None:
                raise InputError(input_path, None, "a video needs --metadata FLIGHT.jsonl "
                                 "(one harborsight.frame/1 object per frame)")
            if masks is not None:
                raise InputError(masks, None, "--masks is for folders of frames")
            source = VideoSource(input_path, metadata, camera=intrinsics)
            segmenter = _segmenter(model)
        options = RunOptions(settings=_settings(method, sections, section_length_m,
                                                pose_margin_px, own_rim_px),
                             overlays=overlays, video=video, video_fps=fps, window_s=window_s)
        vessels = VesselCache(load_vessel_spec(vessel) if vessel else None)
        inputs = {"input": str(input_path), "metadata": str(metadata) if metadata else None,
                  "masks": str(masks) if masks else None}
        summary = _run_flight_with_progress(source, out, vessels, segmenter, options, inputs)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    md = summary.min_distance_m
    console.print(
        f"[green]{summary.measured} of {summary.frames} frame(s) measured[/] in "
        f"{summary.seconds:.1f} s"
        + (f"; closest approach {md:.2f} m (frame {summary.min_distance_frame})"
           if md is not None else "; no obstacle in view"))
    if summary.without_metadata:
        console.print(f"{summary.without_metadata} video frame(s) had no metadata line "
                      "(in the video, not measured)")
    for name, path in summary.outputs.items():
        console.print(f"  {name}: {path}", markup=False, highlight=False)
    if summary.skipped:
        err_console.print(f"[red]{len(summary.skipped)} frame(s) skipped[/] (also in "
                          f"{out / 'run.json'}):")
        for item in summary.skipped:
            err_console.print(f"  {item['error']}", markup=False, highlight=False)
    if summary.warnings:
        err_console.print(f"[yellow]{len(summary.warnings)} warning(s)[/] (frames measured; also "
                          f"in {out / 'run.json'}):")
        for item in summary.warnings:
            err_console.print(f"  {item['warning']}", markup=False, highlight=False)
    raise typer.Exit(1 if summary.skipped and not summary.measured else 0)


def _bundled_samples() -> Path:
    return Path(str(resources.files("harborsight") / "data" / "samples"))


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Where the demo's reports and overlays go.")] = Path(
        "out/demo"),
    method: Annotated[Method, typer.Option(help="Distance method.")] = Method.ground_plane,
) -> None:
    """Measure the bundled sample frames against their exact ground truth, then run the
    bundled 24 s berthing flight (annotated video, distances and closing speeds over time),
    on the exact labels and, if one is packaged, on the default segmentation model."""
    samples = _bundled_samples()
    console.print(f"[bold]harborsight demo[/]: {samples}\n"
                  "Samples are harbour frames rendered by harborsight's Blender simulator "
                  "(harborsight make-samples); masks are their exact labels.")
    try:
        code = _demo_runs(samples, out, method)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    raise typer.Exit(code)


def _demo_runs(samples: Path, out: Path, method: Method) -> int:
    """The demo's three runs; exit code 1 if any bundled frame was skipped (a defect: the
    bundled data are all good)."""
    from harborsight.flight import FolderSource, RunOptions
    from harborsight.perception.default_model import default_model_path
    from harborsight.pipeline import VesselCache

    settings = _settings(method, None, None, POSE_MARGIN_PX, OWN_RIM_PX)
    code = _run_folder(samples, None, VesselCache(), settings, out / "frames", None, True,
                       strict=True)
    flight = samples / "flight"
    console.print(f"\n[bold]flight[/]: {flight} (the tug berthing at "
                  f"{_flight_speed(flight)} m/s, 0.5 s between frames)")
    console.print("[bold]on the exact labels[/]")
    source = FolderSource(flight, flight / "labels", use_masks=True)
    summary = _run_flight_with_progress(
        source, out / "flight", VesselCache(), None, RunOptions(settings=settings),
        {"input": str(flight), "masks": str(flight / "labels")})
    _print_demo_flight(flight, out / "flight", summary)
    failed = bool(summary.skipped)
    if default_model_path().is_file():
        console.print("\n[bold]on the default segmentation model[/]")
        segmenter = _segmenter(None)
        summary = _run_flight_with_progress(
            FolderSource(flight, use_masks=False), out / "flight-model", VesselCache(), segmenter,
            RunOptions(settings=settings), {"input": str(flight), "model": str(segmenter.path)})
        _print_demo_flight(flight, out / "flight-model", summary)
        failed = failed or bool(summary.skipped)
    else:
        console.print("\nno default segmentation model is packaged: the flight ran on labels only")
    return code or (1 if failed else 0)


def _print_demo_flight(flight: Path, out: Path, summary) -> None:
    """Frames measured, closest approach and measured-vs-true closing speed of a demo flight."""
    from harborsight.evaluation.closing import compare_closing_speeds

    md = summary.min_distance_m
    console.print(f"{summary.measured} of {summary.frames} frames measured; closest approach "
                  + (f"{md:.2f} m" if md is not None else "--"))
    comparison = compare_closing_speeds(flight, out / "sections.csv")
    if comparison is not None:
        console.print(
            f"closing speed of the closest section while berthing: measured "
            f"{comparison.measured_mps:.3f} m/s, true {comparison.true_mps:.3f} m/s "
            f"(median over {comparison.samples} frames; true from the ground-truth distances)")
    for name, path in summary.outputs.items():
        console.print(f"  {name}: {path}", markup=False, highlight=False)


def _flight_speed(flight: Path) -> str:
    try:
        return str(json.loads((flight / "dataset.json").read_text())["parameters"][
            "approach_speed_mps"])
    except (OSError, KeyError, json.JSONDecodeError):
        return "?"


@app.command("make-samples")
def make_samples(
    out: Annotated[Path, typer.Option(help="Dataset folder to (re)write.")] = Path("out/samples"),
    seed: Annotated[int, typer.Option(help="Random seed of the layouts.")] = 20260501,
    flight_seed: Annotated[int, typer.Option(help="Random seed of the flight's scene.")] = 8,
) -> None:
    """Regenerate the demo samples (Blender-rendered harbour frames with exact labels and
    ground truth, and the berthing flight; needs the sim extra)."""
    from harborsight.sim.samples import make_demo_flight, make_demo_samples

    try:
        stems = make_demo_samples(out, seed)
        flight = make_demo_flight(out, flight_seed)
    except (HarborsightError, RuntimeError) as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    console.print(f"wrote {len(stems)} frames to {out}/ and a flight of "
                  f"{len(list((flight / 'frames').glob('*.json')))} frames to {flight}/ "
                  f"({json.loads((out / 'dataset.json').read_text())['generator']})",
                  markup=False, highlight=False)


@app.command()
def models(
    num_classes: Annotated[int, typer.Option(min=1, help="Classes of the output layer.")] = 3,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """List the segmentation networks with their parameter counts and input size rule."""
    try:
        from harborsight.perception.networks import (
            NETWORKS,
            create_network,
            inference_parameter_count,
            parameter_count,
        )
    except ImportError as exc:
        err_console.print(f"error: the networks need torch (pip install -e '.[train]'): {exc}")
        raise typer.Exit(2) from None
    rows = []
    for name in NETWORKS:
        network = create_network(name, num_classes, aux_heads=True)
        stride = int(network.output_stride)
        rows.append({
            "name": name,
            "params": inference_parameter_count(network),
            "params_with_aux_heads": parameter_count(network),
            "output_stride": stride,
            "input_size_rule": f"any size; padded inside the model to multiples of {stride}",
        })
    if as_json:
        print(json.dumps(rows, indent=2))
        return
    table = Table(title=f"segmentation networks ({num_classes} classes)", title_justify="left")
    for column in ("network", "params (inference)", "with aux heads", "output stride"):
        table.add_column(column, justify="left" if column == "network" else "right")
    for row in rows:
        table.add_row(row["name"], f"{row['params']:,}", f"{row['params_with_aux_heads']:,}",
                      str(row["output_stride"]))
    console.print(table)
    console.print("input: any frame size; padded inside the model to a multiple of the stride")


class Preset(StrEnum):
    tiny = "tiny"
    default = "default"
    high = "high"


@app.command()
def simulate(
    n: Annotated[int, typer.Option("--n", min=1, help="Frames 0..N-1 (a re-run skips finished ones "
                                   "and a larger N extends the dataset).")],
    out: Annotated[Path, typer.Option(help="Dataset folder (design.md layout).")],
    seed: Annotated[int, typer.Option(help="Dataset seed: frame i is a function of (seed, i).")] = 0,
    altitudes: Annotated[str, typer.Option(
        help="Drone heights above water, m: start:stop:step or a list; frame i flies at "
        "altitude i mod len.")] = "30:150:10",
    workers: Annotated[int, typer.Option(min=1, help="Render processes on this machine.")] = 1,
    preset: Annotated[Preset, typer.Option(
        help="tiny 64x36 (tests), default 640x360, high 1280x720.")] = Preset.default,
    camera: Annotated[str, typer.Option(
        help="Camera preset: dji-mavic3, dji-p4rtk or dji-m30-wide.")] = "dji-mavic3",
    max_tilt_deg: Annotated[float, typer.Option(min=0.0, max=60.0,
                                                help="Largest tilt off nadir, degrees.")] = 15.0,
    vessel: Annotated[Path | None, typer.Option(
        help="vessel.yaml with hull_mesh for the vessel of interest (default: a pool of "
        "procedural vessels).")] = None,
    vessel_pool: Annotated[int, typer.Option(min=1, help="Procedural vessels in the pool.")] = 6,
    scenario: Annotated[str | None, typer.Option(
        help="Only this scenario (alongside, slip, pass, touching, open), or a comma list "
        "cycled by frame index.")] = None,
    split: Annotated[str | None, typer.Option(
        help="Put every frame in this split (e.g. test); default 90 % train, 10 % val.")] = None,
    scheduler: Annotated[str | None, typer.Option(
        help="Dask scheduler address (tcp://host:8786): render on that cluster.")] = None,
    sequence_frames: Annotated[int, typer.Option(
        min=0, help="Flights: this many frames per harbour scene, the vessel berthing toward "
        "its nearest obstacle (0: every frame a new scene).")] = 0,
    frame_interval_s: Annotated[float, typer.Option(
        min=0.01, help="Flights: seconds between frames.")] = 0.5,
    approach_speed_mps: Annotated[float, typer.Option(
        min=0.0, help="Flights: the vessel's closing speed, m/s (it stops 0.5 m short).")] = 0.5,
) -> None:
    """Render a synthetic harbour dataset with Blender: images, labels, instances, frame
    metadata with exact per-section ground truth (needs the sim extra: bpy)."""
    from harborsight.sim.dataset import SimulationConfig, parse_altitudes
    from harborsight.sim.dataset import simulate as run_sim

    try:
        config = SimulationConfig(
            seed=seed, preset=preset.value, altitudes_m=parse_altitudes(altitudes), camera=camera,
            max_tilt_deg=max_tilt_deg, vessel_spec=str(vessel.resolve()) if vessel else None,
            vessel_pool=vessel_pool, scenario=scenario, split=split,
            sequence_frames=sequence_frames, frame_interval_s=frame_interval_s,
            approach_speed_mps=approach_speed_mps)
        config.validate()
        with Progress(TextColumn("[bold]rendering"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn(), TextColumn("{task.fields[status]}"),
                      console=console) as progress:
            task = progress.add_task("frames", total=n, status="")

            def on_frame(result) -> None:
                progress.advance(task)
                if result.error:
                    err_console.print(f"[red]frame {result.index:06d} failed:[/] "
                                      f"{escape(result.error)}")
                else:
                    progress.update(task, status=f"{result.seconds:.1f} s/frame")

            progress.update(task, completed=0)
            summary = run_sim(out, n, config, workers=workers, scheduler=scheduler,
                              on_frame=on_frame)
            progress.update(task, completed=n)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False)
        raise typer.Exit(2) from None
    done = len(summary.rendered)
    rate = f", {summary.seconds / done:.2f} s per frame" if done else ""
    console.print(f"[green]{done} frame(s) rendered[/], {summary.skipped} already there, "
                  f"{len(summary.failed)} failed, in {summary.seconds:.1f} s{rate}; dataset in {out}/")
    if summary.failed:
        raise typer.Exit(1)


@app.command("contact-sheet")
def contact_sheet_command(
    dataset: Annotated[Path, typer.Argument(help="Dataset folder (design.md layout).")],
    out: Annotated[Path, typer.Option(help="PNG to write.")] = Path("out/contact-sheet.png"),
    n: Annotated[int, typer.Option("--n", min=1, help="How many frames (the first N).")] = 8,
    columns: Annotated[int, typer.Option(min=1, help="Frame pairs per row.")] = 2,
    tile_width: Annotated[int, typer.Option(min=64, help="Width of each tile, px.")] = 480,
) -> None:
    """Tile frames with their class masks and the true clearance of every hull section."""
    from harborsight.viz.contact_sheet import contact_sheet

    stems = sorted(p.stem for p in (dataset / "frames").glob("*.json"))[:n]
    if not stems:
        err_console.print(f"error: {dataset / 'frames'}: no frames", markup=False)
        raise typer.Exit(2)
    sheet = contact_sheet(dataset, stems, columns, tile_width)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        err_console.print(f"error: {out.parent}: {exc.strerror or exc}", markup=False,
                          highlight=False)
        raise typer.Exit(2) from None
    if not write_image(out, sheet):
        err_console.print(f"error: {out}: could not be written (a folder that cannot be "
                          "written, or not a .png/.jpg name)", markup=False, highlight=False)
        raise typer.Exit(2)
    console.print(f"wrote {out} ({len(stems)} frames, {sheet.shape[1]}x{sheet.shape[0]} px)",
                  markup=False, highlight=False)


def _need_torch() -> None:
    try:
        import torch  # noqa: F401
    except ImportError as exc:
        err_console.print(f"error: training needs torch (pip install -e '.[train]'): {exc}")
        raise typer.Exit(2) from None


def _parse_crop(text: str, option: str = "crop") -> tuple[int, int]:
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


def _parse_weighted_data(entries: list[Path]) -> tuple[list[str], list[float] | None]:
    """``DIR`` or ``DIR:W`` entries -> folders and weights (None when no entry has one; an
    entry without one then weighs 1)."""
    folders, weights = [], []
    for entry in entries:
        text = str(entry)
        head, _, tail = text.rpartition(":")
        try:
            weight = float(tail) if head and not Path(text).is_dir() else None
        except ValueError:
            weight = None
        folders.append(head if weight is not None else text)
        weights.append(weight)
    if all(w is None for w in weights):
        return folders, None
    return folders, [1.0 if w is None else w for w in weights]


@app.command()
def train(
    out: Annotated[Path, typer.Option(help="Run folder: last.pt, best.pt, train_log.jsonl.")],
    model: Annotated[str | None, typer.Option(
        help="Network: bisenetv2, fchardnet70, ddrnet23_slim, ddrnet23 (see harborsight models).")
    ] = None,
    data: Annotated[list[Path] | None, typer.Option(
        help="Dataset folder (dataset.json, images/, labels/); repeat for several. DIR:W gives "
        "it sampling weight W (e.g. --data sim:0.8 --data real:0.2): each sample comes from a "
        "dataset with probability proportional to its weight, whatever its size; without "
        "weights every training frame is drawn equally often.")] = None,
    val_data: Annotated[list[Path] | None, typer.Option(
        help="Validate (and pick best.pt) on the val split of these folders only, e.g. the "
        "real frames of a mixed run (default: every --data folder that has a val split). With "
        "several, each is scored on its own and best.pt goes to the highest mean of their "
        "mIoUs, so that a small real set counts as much as a large simulator set.")] = None,
    resume: Annotated[bool, typer.Option(
        help="Continue the run in --out from last.pt exactly (other options may only change "
        "--iterations, --val-every, --checkpoint-every, --workers, --threads, --device).")
    ] = False,
    iterations: Annotated[int | None, typer.Option(min=1, help="Optimiser steps [10000].")] = None,
    batch_size: Annotated[int | None, typer.Option(help="Images per step, at least 2 [8].")] = None,
    crop: Annotated[str | None, typer.Option(
        help="Training crop HEIGHTxWIDTH in pixels, or N for NxN [360x360].")] = None,
    fit_large: Annotated[str | None, typer.Option(
        help="HEIGHTxWIDTH, e.g. 360x640 (the model input): frames larger than this are "
        "stretched to it before cropping and validation, smaller ones keep their scale; what "
        "`segment --mode auto` does, so a model trains at the scale it will see [off].")] = None,
    freeze_batchnorm: Annotated[bool | None, typer.Option(
        help="Keep every BatchNorm's running statistics as --init-from left them (BatchNorm "
        "layers in eval mode; their scale and shift still learn): a fine-tune on new data "
        "then does not shift the statistics the model's earlier data was normalised with "
        "[off].")] = None,
    lr: Annotated[float | None, typer.Option(help="Initial learning rate [0.01].")] = None,
    momentum: Annotated[float | None, typer.Option(help="SGD momentum [0.9].")] = None,
    weight_decay: Annotated[float | None, typer.Option(
        help="Weight decay on conv/linear weights [5e-4].")] = None,
    poly_power: Annotated[float | None, typer.Option(help="Poly LR exponent [0.9].")] = None,
    warmup: Annotated[int | None, typer.Option(help="Linear LR warm-up iterations [0].")] = None,
    warmup_ratio: Annotated[float | None, typer.Option(
        help="LR factor at the start of the warm-up [0.1].")] = None,
    aux_weight: Annotated[list[float] | None, typer.Option(
        help="Weight of each auxiliary head's loss, repeated per head [bisenetv2 1 1 1 1, "
        "ddrnet 0.4].")] = None,
    bootstrap_start: Annotated[int | None, typer.Option(
        help="Iteration where the bootstrapped CE starts dropping easy pixels [1000].")] = None,
    bootstrap_end: Annotated[int | None, typer.Option(
        help="Iteration where it reaches --bootstrap-fraction [9000].")] = None,
    bootstrap_fraction: Annotated[float | None, typer.Option(
        help="Share of the hardest pixels kept at the end [0.2].")] = None,
    small_object_weight: Annotated[float | None, typer.Option(
        help="Up-weight small objects' pixels by clip(sqrt(A_ref / area), 1, this); needs the "
        "datasets' instances/ masks; 1: off [1].")] = None,
    small_object_area: Annotated[float | None, typer.Option(
        help="A_ref of --small-object-weight, in pixels: objects this large keep weight 1 "
        "[1000].")] = None,
    augment: Annotated[bool | None, typer.Option(
        help="Mirror/flip/scale/colour/blur/noise/JPEG augmentation; off: random crop only.")
    ] = None,
    train_split: Annotated[str | None, typer.Option(help="Split to train on [train].")] = None,
    val_split: Annotated[str | None, typer.Option(help="Split to validate on [val].")] = None,
    val_every: Annotated[int | None, typer.Option(
        help="Validate (mIoU, best.pt) every N iterations; 0: never [1000].")] = None,
    checkpoint_every: Annotated[int | None, typer.Option(
        help="Write last.pt every N iterations [500].")] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of weights, sampling and augmentation [0].")
    ] = None,
    device: Annotated[str | None, typer.Option(help="auto, cpu or cuda[:N] [auto].")] = None,
    amp: Annotated[bool | None, typer.Option(help="fp16 autocast on CUDA [on].")] = None,
    workers: Annotated[int | None, typer.Option(
        help="DataLoader worker processes [CPU: 0, CUDA: min(8, cores - 1)].")] = None,
    threads: Annotated[int | None, typer.Option(
        help="torch CPU threads; on a shared machine fewer threads than cores can be much "
        "faster [torch's default].")] = None,
    init_from: Annotated[Path | None, typer.Option(
        help="Warm start: begin from this checkpoint's weights, or from an ONNX model written "
        "by `harborsight export` (the shipped default among them; its weights are recovered "
        "and checked against it); same network; optimiser and schedule start afresh. E.g. to "
        "fine-tune the default model on real frames.")] = None,
    progress: Annotated[bool, typer.Option(help="Show the progress bar.")] = True,
) -> None:
    """Train a segmentation network on simulator-layout datasets (needs torch)."""
    _need_torch()
    from harborsight.training.checkpoint import load_checkpoint
    from harborsight.training.loop import LAST, TrainConfig
    from harborsight.training.loop import train as run_training

    try:
        given = {"iterations": iterations, "batch_size": batch_size, "lr": lr,
                 "momentum": momentum, "weight_decay": weight_decay, "poly_power": poly_power,
                 "warmup_iterations": warmup, "warmup_ratio": warmup_ratio,
                 "crop_hw": _parse_crop(crop) if crop else None,
                 "fit_large_hw": _parse_crop(fit_large, "fit_large") if fit_large else None,
                 "freeze_batchnorm": freeze_batchnorm,
                 "aux_weights": tuple(aux_weight) if aux_weight else None,
                 "bootstrap_start_iteration": bootstrap_start,
                 "bootstrap_end_iteration": bootstrap_end,
                 "bootstrap_end_fraction": bootstrap_fraction,
                 "small_object_weight": small_object_weight,
                 "small_object_area_px": small_object_area, "augment": augment,
                 "train_split": train_split, "val_split": val_split, "val_every": val_every,
                 "checkpoint_every": checkpoint_every, "seed": seed, "device": device,
                 "amp": amp, "num_workers": workers, "threads": threads, "model": model,
                 "init_from": str(init_from) if init_from else None,
                 "val_dirs": [str(d) for d in val_data] if val_data else None}
        if data:
            given["data_dirs"], given["data_weights"] = _parse_weighted_data(data)
        given = {k: v for k, v in given.items() if v is not None}
        if resume:
            stored = load_checkpoint(out / LAST)["config"]
            config = TrainConfig.from_dict({**stored, **given, "out_dir": str(out)})
        else:
            if model is None or not data:
                raise InputError(None, "model" if model is None else "data",
                                 "a new run needs --model and --data (or --resume)")
            config = TrainConfig(out_dir=str(out), **given)
        result = run_training(config, resume=resume, console=err_console, show_progress=progress)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    best = "—" if result.best_val_miou is None else f"{result.best_val_miou:.4f}"
    console.print(f"trained {config.model} to iteration {result.iteration}; "
                  f"last: {result.last_checkpoint}; best val mIoU {best}"
                  + (f" ({result.best_checkpoint})" if result.best_checkpoint else ""))


@app.command("average-weights")
def average_weights(
    checkpoint: Annotated[list[Path], typer.Option(
        help="Checkpoint to average (repeat: at least two of one network and lineage).")],
    out: Annotated[Path, typer.Option(help="Checkpoint to write (.pt).")],
    weight: Annotated[list[float] | None, typer.Option(
        help="Weight of each --checkpoint, in order [all equal].")] = None,
) -> None:
    """Average the weights of checkpoints of one lineage ("model soup") into a new checkpoint,
    to export or evaluate like any other."""
    _need_torch()
    from harborsight.training.checkpoint import average_checkpoints, save_checkpoint

    try:
        payload = average_checkpoints(checkpoint, weight)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    options = [f"--checkpoint {shlex.quote(str(path))}" for path in checkpoint]
    options += [f"--weight {w:g}" for w in weight or []]
    payload["command"] = " ".join(["harborsight average-weights", *options,
                                   f"--out {shlex.quote(str(out))}"])
    save_checkpoint(out, payload)
    shares = ", ".join(f"{source['weight']:.3g} × {source['path']} (iteration "
                       f"{source['iteration']})" for source in payload["averaged_from"])
    console.print(f"averaged {payload['network']}: {shares}\ncheckpoint: {out}", markup=False,
                  highlight=False)


telemetry_app = typer.Typer(rich_markup_mode=None,
    no_args_is_help=True,
    help="Real flight logs (DJI SRT, PX4 ULog, ArduPilot BIN) and vessel tracks (NMEA 0183, "
    "CSV): inspect them, and write a video's per-frame metadata for `run`.")
app.add_typer(telemetry_app, name="telemetry")

_UTC_OFFSET_HELP = ("DJI SRT only: hours the SRT's local date lines are ahead of UTC (e.g. 2 "
                    "for CEST), to place them in UTC.")


@telemetry_app.command("show")
def telemetry_show(
    logs: Annotated[list[Path], typer.Argument(
        help="Drone logs (.srt, .ulg, .bin) or vessel tracks (.nmea/.txt/.log NMEA 0183, .csv).")],
    utc_offset_h: Annotated[float | None, typer.Option(
        min=-14.0, max=14.0, help=_UTC_OFFSET_HELP)] = None,
    json_out: Annotated[Path | None, typer.Option(
        "--json", help="Also write the summaries as JSON.")] = None,
) -> None:
    """What each log holds: samples, rate, duration, UTC start, extent, altitude datum,
    attitude, and what was skipped. Exit code 1 if any log could not be read."""
    from harborsight.telemetry import DRONE_LOG_SUFFIXES, read_drone_log
    from harborsight.telemetry.vessel_track import read_vessel_track

    summaries, failed = [], 0
    for path in logs:
        try:
            track = (read_drone_log(path, utc_offset_h) if path.suffix.lower() in DRONE_LOG_SUFFIXES
                     else read_vessel_track(path))
        except HarborsightError as exc:
            err_console.print(f"error: {exc}", markup=False, highlight=False)
            failed += 1
            continue
        summary = track.summary()
        summaries.append(summary)
        table = Table(title=f"{path} ({summary['kind']})", title_justify="left", show_header=False)
        table.add_column("what")
        table.add_column("value")

        def span(values, digits, unit=""):
            return "—" if values is None else f"{values[0]:.{digits}f} to {values[1]:.{digits}f}{unit}"

        rate = summary["rate_hz"]
        table.add_row("samples", f"{summary['samples']} over {summary['duration_s']:.1f} s"
                      + (f" ({rate:.1f} Hz)" if rate else ""))
        table.add_row("clock", summary["clock"])
        table.add_row("UTC at t = 0", summary["utc_start"] or "unknown")
        table.add_row("latitude", span(summary["lat_deg"], 6, "°"))
        table.add_row("longitude", span(summary["lon_deg"], 6, "°"))
        table.add_row("altitude", span(summary["alt_m"], 1, " m")
                      + (f" ({summary['alt_reference']})" if summary["alt_reference"] else ""))
        table.add_row("attitude", {"gimbal": "gimbal (camera)", "vehicle": "airframe"}.get(
            summary["attitude"], "none"))
        if summary["heading"]:
            table.add_row("heading", "true heading")
        for note in summary["notes"]:
            table.add_row("note", note)
        console.print(table)
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(strict_json(summaries, indent=2) + "\n")
    raise typer.Exit(1 if failed else 0)


def _telemetry_camera(camera: str, width: int | None, height: int | None, source: Path) -> dict:
    """A frame/1 camera block from a preset name (with the video's size) or a calibration."""
    from harborsight.geometry.camera import load_camera_calibration
    from harborsight.sim.cameras import CAMERA_PRESETS

    if camera in CAMERA_PRESETS:
        if not width or not height:
            raise InputError(source, "size", f"camera preset {camera!r} needs the image size: "
                             "give --video or --image-size")
        intrinsics = CAMERA_PRESETS[camera].intrinsics(width, height)
    else:
        if not Path(camera).is_file():
            raise InputError(camera, "--camera", "neither a camera preset ("
                             + ", ".join(CAMERA_PRESETS) + ") nor a calibration file")
        intrinsics = load_camera_calibration(Path(camera))
        if width and height and (intrinsics.width, intrinsics.height) != (width, height):
            raise InputError(camera, "calibration", f"calibrated for {intrinsics.width}x"
                             f"{intrinsics.height}, the video is {width}x{height}")
    return {"width": intrinsics.width, "height": intrinsics.height, "fx": intrinsics.fx,
            "fy": intrinsics.fy, "cx": intrinsics.cx, "cy": intrinsics.cy,
            "distortion": list(intrinsics.distortion)}


@telemetry_app.command("video")
def telemetry_video(
    drone_log: Annotated[Path, typer.Argument(help="The drone's log: DJI .srt (video clock), "
                                              "PX4 .ulg or ArduPilot .bin.")],
    vessel_track: Annotated[Path, typer.Option(
        help="The vessel's track: NMEA 0183 (RMC/GGA position; HDT, HDG or HDM heading, "
        "magnetic made true with the WMM) or CSV (time, lat, lon, heading_deg or "
        "heading_mag_deg).")],
    camera: Annotated[str, typer.Option(
        help="Camera: a preset (dji-mavic3, dji-p4rtk, dji-m30-wide) or a calibration file "
        "(OpenCV YAML/XML or ROS camera_info).")],
    water_level_m: Annotated[float, typer.Option(
        min=-1000.0, max=1000.0, help="The water surface in the drone altitude's datum (see "
        "`telemetry show`): e.g. -3.5 for a DJI take-off from a deck 3.5 m above the water.")],
    out: Annotated[Path, typer.Option(help="JSON lines to write, one object per frame.")],
    video: Annotated[Path | None, typer.Option(
        help="The video: its frame count, rate and size.")] = None,
    frames: Annotated[int | None, typer.Option(
        min=1, max=MAX_VIDEO_FRAMES, help="Frame count, without --video.")] = None,
    fps: Annotated[float | None, typer.Option(
        min=0.1, max=MAX_VIDEO_FPS, help="Frame rate, without --video.")] = None,
    image_size: Annotated[str | None, typer.Option(
        help="WIDTHxHEIGHT of the frames, without --video.")] = None,
    video_start: Annotated[str | None, typer.Option(
        help="UTC time of the video's first frame, ISO 8601 (needed for autopilot logs, and "
        "for SRTs without date lines).")] = None,
    utc_offset_h: Annotated[float | None, typer.Option(
        min=-14.0, max=14.0, help=_UTC_OFFSET_HELP)] = None,
    mount: Annotated[str, typer.Option(
        help="auto (the log's gimbal attitude where it has one, else stabilised), gimbal, "
        "stabilised (pointing at --camera-pitch-deg, no roll, the airframe's yaw), or rigid "
        "(fixed to the airframe).")] = "auto",
    camera_pitch_deg: Annotated[float, typer.Option(
        min=-90.0, max=0.0, help="Stabilised or rigid mount: the camera's pitch (-90: "
        "straight down, 0: at the horizon).")] = -90.0,
    camera_yaw_deg: Annotated[float | None, typer.Option(
        help="A fixed camera yaw (degrees clockwise from true north) for logs without "
        "attitude.")] = None,
    vessel_offset_s: Annotated[float, typer.Option(
        min=-86400.0, max=86400.0, help="Seconds added to each frame's UTC time before "
        "reading the vessel track: -5 if the vessel's clock runs 5 s behind.")] = 0.0,
    max_gap_s: Annotated[float, typer.Option(
        min=0.01, max=3600.0, help="Longest gap in a track bridged by interpolation.")] = 1.0,
) -> None:
    """Write per-frame harborsight.frame/1 metadata for a video from the drone's log and the
    vessel's track, for `harborsight run VIDEO --metadata OUT`. Frames outside a track, or in
    a gap, are left out and listed."""
    from datetime import UTC, datetime

    from harborsight.telemetry import read_drone_log
    from harborsight.telemetry.metadata import MOUNTS, CameraMount, build_video_metadata
    from harborsight.telemetry.vessel_track import read_vessel_track

    try:
        if mount not in MOUNTS:
            raise InputError(None, "--mount", f"{mount!r}: expected one of {', '.join(MOUNTS)}")
        width = height = None
        if video is not None:
            capture = cv2.VideoCapture(str(video))
            if not capture.isOpened():
                raise InputError(video, None, "cannot open the video")
            frames = frames or int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
            fps = fps or float(capture.get(cv2.CAP_PROP_FPS))
            width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
            height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
            capture.release()
            if frames <= 0 or not fps or fps <= 0:
                raise InputError(video, None, "could not read the frame count and rate: give "
                                 "--frames and --fps")
            if frames > MAX_VIDEO_FRAMES or fps > MAX_VIDEO_FPS:
                raise InputError(video, None, f"implausible frame count {frames} or rate "
                                 f"{fps:g}/s in the container: give --frames and --fps")
        if image_size:
            size = re.fullmatch(r"(\d+)x(\d+)", image_size.strip().lower())
            if size is None or min(int(size[1]), int(size[2])) < 1:
                raise InputError(None, "--image-size",
                                 f"expected WIDTHxHEIGHT in pixels, got {image_size!r}")
            width, height = int(size[1]), int(size[2])
        if not frames or not fps:
            raise InputError(None, "--frames", "give --video, or --frames and --fps")
        start = None
        if video_start:
            try:
                start = datetime.fromisoformat(video_start.replace("Z", "+00:00"))
            except ValueError:
                raise InputError(None, "--video-start", f"not ISO 8601: {video_start!r}") from None
            start = start.replace(tzinfo=UTC) if start.tzinfo is None else start.astimezone(UTC)
        drone = read_drone_log(drone_log, utc_offset_h)
        vessel = read_vessel_track(vessel_track)
        camera_block = _telemetry_camera(camera, width, height, drone_log)
        result = build_video_metadata(
            drone, vessel, camera_block, frames, fps, water_level_m=water_level_m,
            mount=CameraMount(mount, camera_pitch_deg, camera_yaw_deg), video_start_utc=start,
            vessel_offset_s=vessel_offset_s, max_gap_s=max_gap_s)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("".join(strict_json(frame) + "\n" for frame in result.frames))
    for track in (drone, vessel):
        for note in track.notes:
            err_console.print(f"note: {track.source}: {note}", markup=False, highlight=False)
    console.print(f"{len(result.frames)} of {frames} frame(s) written to {out} (camera mount: "
                  f"{result.mount}, altitude: {drone.alt_reference})", highlight=False)
    if result.skipped:
        reasons = Counter(reason.split(":")[0] for _, reason in result.skipped)
        err_console.print(f"[red]{len(result.skipped)} frame(s) left out[/] (frames "
                          f"{result.skipped[0][0]}..{result.skipped[-1][0]}):")
        for reason, count in reasons.most_common():
            err_console.print(f"  {count} x {reason}", markup=False, highlight=False)
    raise typer.Exit(1 if not result.frames else 0)


evaluate_app = typer.Typer(rich_markup_mode=None, no_args_is_help=True,
                           help="Evaluate models against labelled data.")
app.add_typer(evaluate_app, name="evaluate")


@evaluate_app.callback()
def evaluate_callback() -> None:
    """Evaluate models against labelled data: segmentation (Table II) and distance."""


@evaluate_app.command("segmentation")
def evaluate_segmentation_command(
    data: Annotated[list[Path], typer.Option(
        help="Dataset folder (dataset.json, images/, labels/); repeat for several.")],
    model: Annotated[Path | None, typer.Option(
        help="A torch checkpoint (.pt) or an ONNX model (.onnx); or give --predictions.")] = None,
    split: Annotated[list[str] | None, typer.Option(
        help="Split(s) to score, one table row each [test].")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the metrics as JSON.")
                        ] = None,
    markdown: Annotated[Path | None, typer.Option(help="Write the table as Markdown.")] = None,
    fps_seconds: Annotated[float, typer.Option(
        help="Seconds of timing for the FPS column; 0 skips it.")] = 2.0,
    device: Annotated[str, typer.Option(help="Device of a torch checkpoint: cpu or cuda.")] = "cpu",
    threads: Annotated[int | None, typer.Option(help="CPU threads (default: all).")] = None,
    height_bin_m: Annotated[float, typer.Option(
        help="Also score per drone height above water (frames/*.json), in bins of this many "
        "metres; 0: no breakdown.")] = 10.0,
    by_object: Annotated[bool, typer.Option(
        help="Also score every object on its own (instances/ masks): the share of its pixels "
        "taken for solid, per kind (simulator datasets) and per size in pixels.")] = False,
    mode: Annotated[SegmentMode, typer.Option(
        help="How an ONNX model meets frames of another size than its input: resize (stretch "
        "into the input), tiles (overlapping windows blended) or auto (pad frames no larger "
        "than the input, stretch larger ones: harborsight segment's default), as in "
        "harborsight segment (see its --help); tiles and auto need an ONNX model.")
    ] = SegmentMode.resize,
    tile_overlap: Annotated[float | None, typer.Option(
        min=0.0, max=0.9, show_default=False,
        help="tiles: overlap of neighbouring windows, a fraction of a window [0.25].")] = None,
    tile_scale: Annotated[float | None, typer.Option(
        min=0.01, max=16.0, show_default=False,
        help="tiles: scale each frame by this factor before cutting windows [1.0].")] = None,
    max_side: Annotated[int | None, typer.Option(
        min=1, show_default=False,
        help="tiles: and at most this many pixels on the scaled frame's longer side.")] = None,
    predictions: Annotated[Path | None, typer.Option(
        help="Score the masks in this folder (<stem>.png, e.g. from harborsight segment) "
        "instead of running a model; a frame whose mask is missing or of another size is "
        "listed and skipped.")] = None,
) -> None:
    """Mean accuracy, IoU per class, mIoU, FPS, resolution and parameters (paper Table II)."""
    from harborsight.evaluation.segmentation import evaluate_segmentation
    from harborsight.perception.segment_images import SegmentOptions

    try:
        if (model is None) == (predictions is None):
            raise InputError(None, "--model", "give either --model or --predictions")
        options = SegmentOptions.from_options(mode, tile_overlap, tile_scale, max_side)
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn(), console=console, transient=True) as progress:
            task = progress.add_task("reading frames", total=None)

            def on_split(name: str, n_frames: int) -> None:
                progress.update(task, description=f"scoring {name}", total=n_frames,
                                completed=0)

            result = evaluate_segmentation(
                model, data, split or ["test"], fps_seconds, device, threads,
                on_frame=lambda _: progress.advance(task), height_bin_m=height_bin_m,
                by_object=by_object, on_split=on_split, options=options,
                predictions=predictions)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    how = f"; mode {options.describe()}" if result.model.kind == "onnx" else ""
    source = (f"{result.model.network} ({result.model.kind}{how}): {model}"
              if predictions is None else f"masks in {predictions}")
    console.print(_scores_table(source, "split",
                                [(row.split, row.frames, row.scores) for row in result.rows]))
    for row in result.rows:
        if row.by_height_m:
            console.print(_scores_table(
                f"{row.split} by drone height", "height m",
                [(f"{h:g}", n, sc) for h, (n, sc) in sorted(row.by_height_m.items())]))
            if row.frames_without_height:
                console.print(f"{row.split}: {row.frames_without_height} frame(s) without "
                              "readable metadata are in the totals, not in the table by height",
                              highlight=False)
        if row.objects:
            from harborsight.evaluation.objects import markdown_object_table

            console.print(f"{row.split}: recall per object", highlight=False)
            console.print(markdown_object_table(row.objects), markup=False, highlight=False)
        for _, error in row.skipped:
            err_console.print(f"[red]skipped[/] ({row.split}) {escape(error)}", highlight=False)
    w, h = result.resolution_wh
    if predictions is None:
        console.print(f"speed {_fmt(result.fps, 2)} FPS at {w}x{h}, "
                      f"{result.model.params or 0:,} parameters")
    if json_out:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(strict_json(result.to_dict(), indent=2) + "\n")
        console.print(f"JSON: {json_out}")
    if markdown:
        markdown.parent.mkdir(parents=True, exist_ok=True)
        markdown.write_text(result.markdown())
        console.print(f"Markdown: {markdown}")


def _scores_table(title: str, key_header: str, rows: list[tuple[str, int, object]]) -> Table:
    """Rich table of (key, frames, SegmentationScores) rows: Table II's accuracy/IoU columns."""
    from harborsight.evaluation.segmentation import TABLE_IOU_COLUMNS

    table = Table(title=title, title_justify="left")
    for header in (key_header, "frames", "mean acc %",
                   *(f"IoU {n.lower()} %" for n, _ in TABLE_IOU_COLUMNS), "mIoU %"):
        table.add_column(header, justify="left" if header == "split" else "right")
    for key, frames, sc in rows:
        table.add_row(key, str(frames), _fmt(100 * sc.mean_accuracy, 1),
                      *(_fmt(100 * sc.iou[c], 1) for _, c in TABLE_IOU_COLUMNS),
                      _fmt(100 * sc.miou, 1))
    return table


@evaluate_app.command("distance")
def evaluate_distance_command(
    data: Annotated[Path, typer.Option(help="Simulator dataset with ground truth (frames/*.json).")],
    out: Annotated[Path, typer.Option(help="Folder for sections.csv, summary.md/json and plots.")
                   ] = Path("out/evaluate-distance"),
    oracle: Annotated[bool, typer.Option(
        help="Measure on the simulator's exact labels (separates segmentation errors).")] = True,
    flat_world: Annotated[bool, typer.Option(
        help="Also measure on flat-world masks (scene footprints on the water plane): "
        "pixel quantisation alone, which separates the planar assumption.")] = False,
    model: Annotated[Path | None, typer.Option(
        help="Also measure on masks from this ONNX model; 'default' for the shipped one.")] = None,
    methods: Annotated[str, typer.Option(help="Comma list of gsd, ground_plane.")
                       ] = "gsd,ground_plane",
    split: Annotated[str | None, typer.Option(help="Only frames of this split.")] = None,
    limit: Annotated[int | None, typer.Option(min=1, help="At most this many frames.")] = None,
    by_obstacle: Annotated[bool, typer.Option(
        help="Also attribute each true distance to the kind of object it is measured to "
        "(quay, pier, ship, ...; rebuilds each simulator scene, about 0.3 s a frame) and "
        "summarise the signed error per kind (by_obstacle.md/json) and the summed error per "
        "kind and per what the reported point lies on (error_budget.md/json).")] = False,
    worst: Annotated[int, typer.Option(
        min=0, help="Draw the N frames with the largest summed error of each configuration "
        "(overlay | simulator labels | measured masks) to worst/.")] = 0,
    pose_margin_px: Annotated[float, typer.Option(
        min=0.0, help="Growth of the vessel's own image region for pose and mask error, as "
        "in measure [2 px]: wider hides more of a model's vessel blob spilling onto the "
        "water, and reports a touching obstacle that much farther away.")] = POSE_MARGIN_PX,
    own_rim_px: Annotated[int, typer.Option(min=0, help=_OWN_RIM_HELP)] = OWN_RIM_PX,
) -> None:
    """Per-section distance error against ground truth by altitude: CSV, Markdown, box and
    bar plots, side by side for each mask source and conversion method."""
    from harborsight.clearance.measure import ClearanceSettings
    from harborsight.evaluation.distance import (
        attribute_obstacles,
        evaluate_frames,
        flat_world_masks,
        load_frames,
        markdown_table,
        model_masks,
        oracle_masks,
        truth_obstacle_kinds,
        write_outputs,
    )

    clearance = ClearanceSettings(pose_margin_px=pose_margin_px, own_rim_px=own_rim_px)
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    bad = [m for m in chosen if m not in {m.value for m in Method}]
    if bad or not chosen:
        err_console.print(f"error: --methods: unknown {bad}; use gsd and/or ground_plane")
        raise typer.Exit(2)
    sources = []
    if oracle:
        sources.append(("oracle", oracle_masks))
    try:
        if flat_world:
            sources.append(("flat", flat_world_masks(data)))
        if model is not None:
            from harborsight.perception.default_model import load_default_segmenter

            segmenter = load_default_segmenter(None if str(model) == "default" else model)
            name = segmenter.sidecar.get("network") or Path(segmenter.path).stem
            sources.append((f"model:{name}", model_masks(segmenter.segment)))
        if not sources:
            raise InputError(None, "--oracle/--model", "nothing to evaluate: keep --oracle, "
                             "or give --flat-world or --model")
        unreadable: list[tuple[str, str]] = []
        frames = load_frames(data, split, unreadable)[:limit]
        if not frames:
            raise InputError(data / "frames", None, "no frames" + (f" in split {split}" if split else ""))
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False)
        raise typer.Exit(2) from None
    results, skipped = [], list(unreadable)
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True) as progress:
        for masks_name, source in sources:
            for method in chosen:
                task = progress.add_task(f"{masks_name} {method}", total=len(frames))

                def done(stem: str, error: str | None, task=task) -> None:
                    progress.advance(task)
                    if error:
                        skipped.append((stem, error))

                results += evaluate_frames(data, frames, masks_name, source, method, done,
                                           clearance)
        if by_obstacle:
            kinds_of, kinds = truth_obstacle_kinds(data), {}
            task = progress.add_task("obstacle kinds", total=len(frames))
            for frame in frames:
                stem = Path(frame["image"]).stem
                try:
                    kinds[stem] = kinds_of(frame)
                except (HarborsightError, KeyError, ValueError) as exc:
                    skipped.append((stem, f"obstacle kinds: {type(exc).__name__}: {exc}"))
                progress.advance(task)
            attribute_obstacles(results, kinds)
    written = write_outputs(results, out)
    drawn = _draw_worst_frames(data, frames, results, sources, chosen, out / "worst", worst,
                               skipped, clearance)
    print(markdown_table(written["rows"]))
    if written["by_obstacle"]:
        from harborsight.evaluation.distance import markdown_obstacle_table

        print(markdown_obstacle_table(written["by_obstacle"]))
    learned = [r for r in written["error_sources"] if r.masks.startswith("model:")]
    if learned:
        from harborsight.evaluation.distance import markdown_error_source_table

        print("Where the model's error comes from (the reported obstacle point in the "
              "simulator's masks):\n")
        print(markdown_error_source_table(learned))
    for (stem, error), times in Counter(skipped).items():   # once per frame and reason
        repeat = f" (in {times} evaluations)" if times > 1 else ""
        err_console.print(f"[red]skipped[/] {escape(f'{stem}: {error}{repeat}')}",
                          highlight=False)
    console.print(f"{len(frames)} frame(s), {len(results)} section results; "
                  f"written to {out}/ (sections.csv, summary.md, summary.json, "
                  + ", ".join(p.name for p in written["plots"])
                  + (", error_sources.md, error_sources.json" if written["error_sources"] else "")
                  + (", by_obstacle.md, by_obstacle.json" if written["by_obstacle"] else "")
                  + (", error_budget.md, error_budget.json" if written["error_budget"] else "")
                  + (f", {drawn} picture(s) in worst/" if drawn else "") + ")")


def _draw_worst_frames(data: Path, frames: list[dict], results: list, sources: list,
                       methods: list[str], out_dir: Path, count: int,
                       skipped: list[tuple[str, str]], clearance: ClearanceSettings) -> int:
    """``count`` worst frames of every (masks, method) as panels in ``out_dir``; a frame
    that cannot be drawn joins ``skipped``. Returns how many pictures were written."""
    from harborsight.evaluation.distance import draw_error_panel, worst_frames

    by_stem = {Path(f["image"]).stem: f for f in frames}
    written = 0
    for masks_name, source in sources:
        for method in methods:
            for rank, (stem, _) in enumerate(worst_frames(results, masks_name, method, count), 1):
                try:
                    panel = draw_error_panel(data, by_stem[stem], source, method, masks_name,
                                             clearance)
                except (HarborsightError, KeyError) as exc:
                    skipped.append((stem, f"worst-frame picture: {type(exc).__name__}: {exc}"))
                    continue
                out_dir.mkdir(parents=True, exist_ok=True)
                name = f"{masks_name.replace(':', '-')}-{method}-{rank:02d}-{stem}.png"
                if write_image(out_dir / name, panel):
                    written += 1
                else:
                    skipped.append((stem, f"worst-frame picture: {out_dir / name} could not "
                                          "be written"))
    return written


@app.command("export")
def export_command(
    checkpoint: Annotated[Path, typer.Option(help="Checkpoint from harborsight train (best.pt).")],
    out: Annotated[Path, typer.Option(help="ONNX file to write; the sidecar goes beside it (.json).")],
    height: Annotated[int | None, typer.Option(
        min=1, help="Input rows (default: the training frames' height).")] = None,
    width: Annotated[int | None, typer.Option(
        min=1, help="Input columns (default: the training frames' width).")] = None,
    int8: Annotated[bool, typer.Option(
        help="Also write a statically quantised int8 model (<out>.int8.onnx).")] = False,
    calibration_data: Annotated[list[Path] | None, typer.Option(
        help="Dataset folder(s) for int8 calibration, the fp32/int8 mIoU check and the "
        "ONNX-vs-torch check images.")] = None,
    calibration_split: Annotated[list[str] | None, typer.Option(
        help="Split(s) of the calibration data to use [all].")] = None,
    calibration_frames: Annotated[int, typer.Option(
        min=1, help="Frames used to calibrate the int8 ranges.")] = 16,
) -> None:
    """Export a checkpoint to ONNX (uint8 BGR in, logits and labels out) with a JSON sidecar."""
    _need_torch()
    from harborsight.training.export import export_checkpoint

    try:
        result = export_checkpoint(checkpoint, out, height, width, int8, calibration_data,
                                   calibration_split, calibration_frames)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    for _, error in result.skipped_frames:
        err_console.print(f"[red]skipped calibration frame[/] {escape(error)}", highlight=False)
    console.print(f"ONNX: {result.onnx_path}\nsidecar: {result.sidecar_path}")
    relative = result.max_abs_difference / max(result.max_abs_logit, 1e-12)
    console.print(f"ONNX Runtime vs torch: max |logit difference| {result.max_abs_difference:.2e} "
                  f"(logits up to {result.max_abs_logit:.2e}; relative {relative:.1e})")
    if result.int8_path:
        int8_info = result.sidecar["int8"]
        console.print(f"int8: {result.int8_path}; mIoU fp32 {_fmt(result.miou_fp32, 4)}, "
                      f"int8 {_fmt(result.miou_int8, 4)} on {int8_info['evaluation_frames']} "
                      f"frame(s); labels agree on {100 * result.int8_label_agreement:.2f}% of pixels")


def main() -> None:
    try:
        app()
    except InputError as exc:  # pragma: no cover - commands catch their own
        err_console.print(f"error: {exc}", markup=False)
        raise SystemExit(2) from None


"""The ``measure`` command: one image or a folder of frames, a report and an overlay each."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.table import Table

from harborsight.cli.app import (
    FLIPS_HELP,
    MAX_MARGIN_PX,
    OWN_MOTION_HELP,
    OWN_RIM_HELP,
    OWN_RIM_PX,
    POSE_MARGIN_PX,
    REFINE_POSE_HELP,
    SEGMENT_GSD_HELP,
    SIGMA_HELP,
    Method,
    app,
    check_masks_folder,
    clearance_settings,
    console,
    err_console,
    fmt_number,
    load_segmenter,
    print_pose_refinement_summary,
    vessel_cache,
)
from harborsight.cli.listing import grouped_lines
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_folder
from harborsight.progress import progress_report

if TYPE_CHECKING:  # imported by the commands that use them: the CLI starts faster
    from harborsight.clearance.measure import ClearanceSettings
    from harborsight.pipeline import FrameOutcome, VesselCache


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
    table.add_column("± m", justify="right")
    table.add_column("≥ m (95 %)", justify="right")
    table.add_column("pixels", justify="right")
    if truth:
        table.add_column("truth m", justify="right")
        table.add_column("error px", justify="right")
    table.add_column("notes")
    for s in report.sections:
        notes = ", ".join(n for n, on in (("contact", s.contact), ("cut by frame", s.truncated)) if on)
        nearest_m = s.distance_lower_m if s.distance_lower_m is not None else s.distance_m
        style = "bold red" if s.status == STATUS_OK and nearest_m < 2 else None
        row = [str(s.index), s.status, fmt_number(s.distance_m, 2), fmt_number(s.sigma_m, 2),
               fmt_number(s.distance_lower_m, 2), fmt_number(s.distance_px, 1)]
        if truth:
            t = truth.get(s.index)
            err = (None if s.distance_m is None or t is None
                   else (s.distance_m - t) / report.gsd_m_per_px)
            row += [fmt_number(t, 2), fmt_number(err, 2)]
        table.add_row(*row, notes, style=style)
    console.print(table)
    md = report.min_distance_m
    if report.sensors_contradicted:
        from harborsight.clearance.gross_errors import CONTRADICTION_ADVICE

        reason = (report.pose_refinement or {}).get("reason")
        console.print(f"[bold red]the image contradicts the sensors' pose ({reason}): no "
                      f"distance of this frame is trusted; {CONTRADICTION_ADVICE}[/bold red]")
    else:
        console.print(f"closest: section {report.closest_section} at {fmt_number(md, 2)} m"
                      if md is not None else "no obstacle in view")


def run_folder(folder: Path, masks: Path | None, vessels: VesselCache,
                settings: ClearanceSettings, out: Path, camera, show_tables: bool,
                model: Path | None = None, strict: bool = False, flips: int = 1,
                segment_gsd_m: float = 0.0) -> int:
    """Measure a folder; exit code 1 if every frame failed (``strict``: if any did), 130
    when Ctrl-C stopped it (after the frame in hand: the reports and overlays written are
    whole)."""
    from harborsight.cli.run import stop_on_interrupt
    from harborsight.pipeline import discover_jobs, run_batch

    jobs = discover_jobs(folder, masks, segment=model is not None)
    segmenter = (load_segmenter(model, flips=flips, segment_gsd_m=segment_gsd_m)
                 if any(job.mask_path is None for job in jobs) else None)
    if segmenter is None and flips != 1:
        raise InputError(masks or folder, "--flips", "every frame has a mask: test-time flips "
                         "are for a model's masks")
    if segmenter is None and segment_gsd_m:
        raise InputError(masks or folder, "--segment-gsd-m", "every frame has a mask: the GSD "
                         "a model sees is for a model's masks")
    measured = skipped = 0
    try:
        with stop_on_interrupt() as stop, progress_report("measure", len(jobs), console) as report:

            def done(outcome: FrameOutcome) -> None:
                nonlocal measured, skipped
                measured += outcome.error is None
                skipped += outcome.error is not None
                report.advance(note=f"{skipped} skipped" if skipped else "")
                if stop.requested:
                    raise KeyboardInterrupt

            outcomes = run_batch(jobs, vessels, settings, out, camera, on_done=done,
                                 segmenter=segmenter)
    except KeyboardInterrupt:
        err_console.print(f"interrupted: {measured} of {len(jobs)} frame(s) measured before "
                          f"Ctrl-C; the reports and overlays so far are in {out}",
                          markup=False, highlight=False)
        return 130
    good = [o for o in outcomes if o.error is None]
    bad = [o for o in outcomes if o.error is not None]
    if show_tables:
        for outcome in good:
            print_report_table(outcome)
    console.print(f"[green]{len(good)} frame(s) measured[/]; reports and overlays in {escape(str(out))}/")
    print_pose_refinement_summary([o.report.pose_refinement for o in good])
    if bad:
        err_console.print(f"[red]{len(bad)} frame(s) skipped:[/]")
        for line in grouped_lines((outcome.job.stem, f"{outcome.job.stem}: {outcome.error}",
                                   outcome.job.stem) for outcome in bad):
            err_console.print(line, markup=False)
    return 1 if bad and (strict or not good) else 0


def input_folders(*given: Path | None) -> tuple[Path, ...]:
    """The folders a command reads: each given path, and a frame folder's frames/ and
    images/ (its outputs must go elsewhere)."""
    folders = []
    for path in given:
        if path is None:
            continue
        folders.append(path)
        if path.is_dir():
            folders += [path / "frames", path / "images"]
    return tuple(folders)


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
        min=0.1, max=10_000.0,
        help="Section length in metres (overrides the vessel spec).")] = None,
    camera: Annotated[Path | None, typer.Option(
        help="Camera calibration (OpenCV FileStorage YAML/XML or ROS camera_info YAML) "
        "that replaces the frames' intrinsics.")] = None,
    pose_margin_px: Annotated[float, typer.Option(
        min=0.0, max=MAX_MARGIN_PX,
        help="Growth in pixels of the vessel's own image region, for pose and mask "
        "error.")] = POSE_MARGIN_PX,
    own_rim_px: Annotated[int, typer.Option(min=0, max=MAX_MARGIN_PX, help=OWN_RIM_HELP)] = OWN_RIM_PX,
    refine_pose: Annotated[bool, typer.Option(help=REFINE_POSE_HELP)] = True,
    own_motion: Annotated[bool, typer.Option(help=OWN_MOTION_HELP)] = True,
    sigma: Annotated[list[str] | None, typer.Option(metavar="NAME=VALUE", help=SIGMA_HELP)] = None,
    tables: Annotated[bool, typer.Option(help="Print a table per frame.")] = True,
    flips: Annotated[int, typer.Option(help="Frames a model labels: " + FLIPS_HELP)] = 1,
    segment_gsd_m: Annotated[float, typer.Option(
        help="Frames a model labels: " + SEGMENT_GSD_HELP)] = 0.0,
) -> None:
    """Measure hull clearance per section and write a report and an overlay per frame."""
    from harborsight.geometry.calibration_files import load_camera_calibration
    from harborsight.perception.flips import flip_views
    from harborsight.pipeline import FrameJob, measure_job

    try:
        flip_views(flips)
        if model is not None and (mask is not None or masks is not None):
            raise InputError(model, "model", "give either --model or --mask/--masks, not both")
        settings = clearance_settings(method, sections, section_length_m, pose_margin_px, own_rim_px,
                                      refine_pose, sigma, own_motion)
        prepare_output_folder(out, "--out", inputs=input_folders(input_path, meta, mask, masks))
        intrinsics = load_camera_calibration(camera) if camera else None
        vessels = vessel_cache(vessel)
        if input_path.is_dir():
            for name, given in (("--meta", meta), ("--mask", mask)):
                if given is not None:
                    raise InputError(given, name, f"{name} is for a single image; a folder's "
                                     "frames carry their own JSON files (and masks: --masks)")
            check_masks_folder(masks)
            raise typer.Exit(run_folder(input_path, masks, vessels, settings, out, intrinsics,
                                         tables, model, flips=flips,
                                         segment_gsd_m=segment_gsd_m))
        if masks is not None:
            raise InputError(masks, "--masks", "--masks is for folders; give a single image's "
                             "mask with --mask")
        meta_path = meta or input_path.with_suffix(".json")
        job = FrameJob(input_path.stem, meta_path, input_path, mask)
        if mask is not None and flips != 1:
            raise InputError(mask, "--flips", "test-time flips are for a model, not --mask")
        if mask is not None and segment_gsd_m:
            raise InputError(mask, "--segment-gsd-m", "the GSD a model sees is for a model, "
                             "not --mask")
        segmenter = (load_segmenter(model, flips=flips, segment_gsd_m=segment_gsd_m)
                     if mask is None else None)
        outcome = measure_job(job, vessels, settings, out, intrinsics, segmenter=segmenter)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        err_console.print("interrupted: Ctrl-C before the measurement was written",
                          markup=False, highlight=False)
        raise typer.Exit(130) from None
    if tables:
        print_report_table(outcome)
    console.print(f"report: {outcome.report_path}\noverlay: {outcome.overlay_path}",
                  markup=False, highlight=False)

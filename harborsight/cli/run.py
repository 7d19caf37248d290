"""The ``run`` command: a whole flight (a folder of frames or a video with its metadata)."""

from __future__ import annotations

import json
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer

from harborsight.cli.app import (
    FLIPS_HELP,
    MAX_MARGIN_PX,
    MAX_VIDEO_FPS,
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
    load_segmenter,
    print_pose_refinement_summary,
    vessel_cache,
)
from harborsight.cli.listing import grouped_lines
from harborsight.cli.measure import input_folders
from harborsight.cli.progress import progress_report
from harborsight.cli.usage import use_plain_usage_names
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_folder

use_plain_usage_names()      # INPUT, not {INPUT}, in every command's usage line


class StopRequest:
    """Whether Ctrl-C (SIGINT) was pressed, for work that stops between two items."""

    def __init__(self) -> None:
        self.requested = False


@contextmanager
def stop_on_interrupt() -> Iterator[StopRequest]:
    """Turn the first SIGINT into a request to stop after the item in hand (so that what
    is on disk is whole and counted); a second one interrupts at once. The previous handler
    is back on exit. Outside the main thread (where no handler can be set) SIGINT keeps its
    own meaning."""
    request = StopRequest()

    def first(signum, frame) -> None:
        request.requested = True
        signal.signal(signal.SIGINT, signal.default_int_handler)    # a second: at once

    try:
        previous = signal.signal(signal.SIGINT, first)
    except ValueError:                  # not the main thread
        yield request
        return
    try:
        yield request
    finally:
        signal.signal(signal.SIGINT, previous)


def run_flight_with_progress(source, out: Path, vessels, segmenter, options, inputs: dict):
    """:func:`harborsight.flight.run_flight` over ``source`` (a Folder- or VideoSource) with a
    progress display (:mod:`harborsight.cli.progress`) that counts skipped frames. Ctrl-C
    stops the run after the frame in hand: :class:`KeyboardInterrupt` is raised with
    ``run.json`` written, its counts those of the reports on disk."""
    from harborsight.flight import run_flight
    from harborsight.flight.sources import NO_METADATA

    skipped = 0
    with stop_on_interrupt() as stop, progress_report(
            "run", source.frame_count or None, console) as report:

        def advance(frame) -> None:
            nonlocal skipped
            if frame.is_frame:          # not a metadata line without a picture
                skipped += frame.error not in (None, NO_METADATA)
                report.advance(note=f"{skipped} skipped" if skipped else "")
            if stop.requested:          # between two frames: every output is whole
                raise KeyboardInterrupt

        for warning in getattr(source, "warnings", ()):
            console.print(f"warning: {warning}")
        return run_flight(source.frames(), out, vessels, segmenter, options,
                          source_fps=source.fps, inputs=inputs, on_frame=advance,
                          source_warnings=getattr(source, "warnings", ()),
                          frame_size=getattr(source, "size", None))


def interrupted_line(out: Path) -> str:
    """The one line ``run`` prints when Ctrl-C stopped it: what its run.json records."""
    try:
        record = json.loads((out / "run.json").read_text())
        done = f"{record['measured']} of {record['frames']} frame(s) measured"
    except (OSError, ValueError, KeyError, TypeError):
        return f"interrupted: the run stopped before writing {out / 'run.json'}"
    return f"interrupted: {done} before Ctrl-C; the outputs so far and run.json are in {out}"


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
        min=0.1, max=10_000.0,
        help="Section length in metres (overrides the vessel spec).")] = None,
    camera: Annotated[Path | None, typer.Option(
        help="Camera calibration (OpenCV YAML/XML or ROS camera_info) replacing the frames' "
        "intrinsics.")] = None,
    pose_margin_px: Annotated[float, typer.Option(
        min=0.0, max=MAX_MARGIN_PX,
        help="Growth in pixels of the vessel's own image region.")] = POSE_MARGIN_PX,
    own_rim_px: Annotated[int, typer.Option(min=0, max=MAX_MARGIN_PX, help=OWN_RIM_HELP)] = OWN_RIM_PX,
    refine_pose: Annotated[bool, typer.Option(help=REFINE_POSE_HELP)] = True,
    own_motion: Annotated[bool, typer.Option(help=OWN_MOTION_HELP)] = True,
    sigma: Annotated[list[str] | None, typer.Option(metavar="NAME=VALUE", help=SIGMA_HELP)] = None,
    overlays: Annotated[bool, typer.Option(help="Write an annotated PNG per frame.")] = True,
    video: Annotated[bool, typer.Option(help="Write annotated.mp4.")] = True,
    fps: Annotated[float | None, typer.Option(
        min=0.1, max=MAX_VIDEO_FPS,
        help="Frame rate of annotated.mp4. Default: the input "
        "video's, else from the frames' timestamps, else 5.")] = None,
    window_s: Annotated[float, typer.Option(
        min=0.1, max=3600.0,
        help="Closing speed: least-squares fit over this many seconds.")
    ] = 2.0,
    flips: Annotated[int, typer.Option(help=FLIPS_HELP)] = 1,
    segment_gsd_m: Annotated[float, typer.Option(help=SEGMENT_GSD_HELP)] = 0.0,
) -> None:
    """Measure a whole flight: every frame segmented, measured and annotated; distances and
    closing speeds per section over time. A bad frame is reported and skipped."""
    from harborsight.flight import FolderSource, RunOptions, VideoSource
    from harborsight.geometry.calibration_files import load_camera_calibration
    from harborsight.perception.flips import flip_views

    running = False         # whether run_flight has started (and owns run.json)
    try:
        flip_views(flips)
        if not input_path.exists():
            raise InputError(input_path, None, "not found (give a folder of frames, or a video "
                             "with --metadata)")
        prepare_output_folder(out, "--out", inputs=input_folders(input_path, metadata, masks))
        intrinsics = load_camera_calibration(camera) if camera else None
        if input_path.is_dir():
            if metadata is not None:
                raise InputError(metadata, None, "--metadata is for videos; a folder's frames "
                                 "carry their own JSON files")
            if model is not None and masks is not None:
                raise InputError(model, "model", "give either --model or --masks, not both")
            check_masks_folder(masks)
            source = FolderSource(input_path, masks, use_masks=masks is not None,
                                  camera=intrinsics)
            segmenter = (None if masks is not None
                         else load_segmenter(model, flips=flips, segment_gsd_m=segment_gsd_m))
        else:
            if metadata is None:
                raise InputError(input_path, None, "a video needs --metadata FLIGHT.jsonl "
                                 "(one harborsight.frame/1 object per frame)")
            if masks is not None:
                raise InputError(masks, None, "--masks is for folders of frames")
            source = VideoSource(input_path, metadata, camera=intrinsics)
            segmenter = load_segmenter(model, flips=flips, segment_gsd_m=segment_gsd_m)
        if segmenter is None and flips != 1:
            raise InputError(masks, "--flips", "test-time flips are for a model, not --masks")
        if segmenter is None and segment_gsd_m:
            raise InputError(masks, "--segment-gsd-m", "the GSD a model sees is for a model, "
                             "not --masks")
        options = RunOptions(settings=clearance_settings(method, sections, section_length_m,
                                                pose_margin_px, own_rim_px, refine_pose, sigma, own_motion),
                             overlays=overlays, video=video, video_fps=fps, window_s=window_s)
        vessels = vessel_cache(vessel)
        inputs = {"input": str(input_path), "metadata": str(metadata) if metadata else None,
                  "masks": str(masks) if masks else None}
        running = True
        summary = run_flight_with_progress(source, out, vessels, segmenter, options, inputs)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    except KeyboardInterrupt:
        err_console.print(interrupted_line(out) if running else
                          "interrupted: before the first frame; nothing written",
                          markup=False, highlight=False)
        raise typer.Exit(130) from None
    md = summary.min_distance_m
    console.print(
        f"[green]{summary.measured} of {summary.frames} frame(s) measured[/] in "
        f"{summary.seconds:.1f} s"
        + (f"; closest approach {md:.2f} m (frame {summary.min_distance_frame})"
           if md is not None else "; no obstacle in view"))
    print_pose_refinement_summary(summary.pose_refinements)
    if summary.without_metadata:
        console.print(f"{summary.without_metadata} video frame(s) had no metadata line "
                      "(in the video, not measured)")
    for name, path in summary.outputs.items():
        console.print(f"  {name}: {path}", markup=False, highlight=False)
    if summary.skipped:
        err_console.print(f"[red]{len(summary.skipped)} frame(s) skipped[/] (every one in "
                          f"{out / 'run.json'}):")
        for line in grouped_lines((item["frame"], item["error"], item["source"])
                                  for item in summary.skipped):
            err_console.print(line, markup=False, highlight=False)
    if summary.warnings:
        err_console.print(f"[yellow]{len(summary.warnings)} warning(s)[/] (frames measured; every "
                          f"one in {out / 'run.json'}):")
        for line in grouped_lines((item["frame"], item["warning"], item["source"])
                                  for item in summary.warnings):
            err_console.print(line, markup=False, highlight=False)
    raise typer.Exit(1 if summary.skipped and not summary.measured else 0)

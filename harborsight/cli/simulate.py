"""The simulator commands: ``simulate`` (render a dataset) and ``contact-sheet``."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from harborsight.cli.app import (
    app,
    console,
    err_console,
)
from harborsight.errors import HarborsightError, InputError
from harborsight.files import write_image
from harborsight.progress import progress_report


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
        help="Only this scenario (alongside, slip, pass, touching, open; or the families that "
        "look like real harbours: lakeshore, marina, commercial, fishing), a comma list cycled "
        "by frame "
        "index, or "
        "weights to draw from, e.g. lakeshore=0.4,marina=0.4,alongside=0.2. Default: the five "
        "classic scenarios with the weights of docs/simulator.md.")] = None,
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
    pose_noise: Annotated[str | None, typer.Option(
        metavar="GPS,HEADING_DEG,HEIGHT_M",
        help="Write frame metadata with sensor errors: GPS horizontal RMS per receiver (rtk, "
        "dgps, standalone or metres), one sigma of camera yaw and vessel heading (deg), of "
        "height (m), e.g. standalone,2,1. The true pose stays in ground_truth.true_pose; as "
        "dataset add-pose-noise does on a finished dataset.")] = None,
    cull_out_of_view: Annotated[bool, typer.Option(
        help="Build in Blender only the objects that can show in the frame, directly, by "
        "their shadow or in reflection (labels unchanged, RGB within a few grey levels at a "
        "few pixels; 10-20 % faster on marinas). A dataset rendered before this option "
        "resumes only with --no-cull-out-of-view.")] = True,
    wakes: Annotated[bool, typer.Option(
        help="Paint the white water of boats under way (turbulent wake, Kelvin arms, bow "
        "wave) on the rendered water; labels unchanged. A dataset rendered before this "
        "option resumes only with --no-wakes.")] = True,
    auto_exposure: Annotated[bool, typer.Option(
        help="Meter the realistic families' frames as a drone camera does: a gain in linear "
        "light to a mean L* drawn from real drone photos' (50 ± 2.5); classic scenes keep "
        "the render's exposure. A dataset rendered before this option resumes only with "
        "--no-auto-exposure.")] = True,
    leisure_vessels: Annotated[bool, typer.Option(
        help="Centre lake-shore and marina scenes on a leisure craft of 6-16 m (white-heavy "
        "hull colours, from a pool of its own), as real ones are; classic scenes and the "
        "other families keep the 18-70 m pool; with --vessel, that vessel is used "
        "throughout. A dataset rendered before this option resumes only with "
        "--no-leisure-vessels.")] = True,
    berth_views: Annotated[bool, typer.Option(
        help="Let 40 % of the marina frames look along the berths on one side (the camera "
        "aims up to a lane and a half across the rows, the vessel perhaps out of view), as "
        "real pictures of marinas do; the scenes are the same. A dataset rendered before "
        "this option resumes only with --no-berth-views. Never in a flight "
        "(--sequence-frames), whose frames follow the berthing vessel.")] = True,
    dense_marinas: Annotated[bool, typer.Option(
        help="Marinas of 3-6 rows of pontoons a side with 5 % of berths empty, each a boat's "
        "beam and a finger pier wide, as real marinas are; off: the sparser marinas of "
        "before (2-4 rows, 15 % empty). A dataset rendered before this option resumes only "
        "with --no-dense-marinas.")] = True,
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
            approach_speed_mps=approach_speed_mps,
            pose_noise=parse_pose_noise_option(pose_noise) if pose_noise else None,
            cull_out_of_view=cull_out_of_view, wakes=wakes,
            auto_exposure=auto_exposure, leisure_vessels=leisure_vessels,
            berth_views=berth_views, dense_marinas=dense_marinas)
        config.validate()
        with progress_report("simulate", n, console, transient=False) as progress:

            def on_frame(result) -> None:
                if result.error:
                    progress.advance()
                    err_console.print(f"[red]frame {result.index:06d} failed:[/] "
                                      f"{escape(result.error)}")
                else:
                    progress.advance(note=f"{result.seconds:.1f} s/frame")

            summary = run_sim(out, n, config, workers=workers, scheduler=scheduler,
                              on_frame=on_frame)
            progress.update(completed=n)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False)
        raise typer.Exit(2) from None
    done = len(summary.rendered)
    rate = f", {summary.seconds / done:.2f} s per frame" if done else ""
    console.print(f"[green]{done} frame(s) rendered[/], {summary.skipped} already there, "
                  f"{len(summary.failed)} failed, in {summary.seconds:.1f} s{rate}; dataset in {out}/")
    if summary.failed:
        raise typer.Exit(1)


def parse_pose_noise_option(text: str) -> dict:
    """``GPS,HEADING_DEG,HEIGHT_M`` of ``--pose-noise`` as PoseNoise fields."""
    from harborsight.sim.pose_noise import parse_gps_noise

    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 3:
        raise InputError(None, "--pose-noise", f"expected GPS,HEADING_DEG,HEIGHT_M (e.g. "
                         f"standalone,2,1), got {text!r}")
    try:
        gps_m = parse_gps_noise(parts[0])
        heading_deg, height_m = float(parts[1]), float(parts[2])
    except ValueError as exc:
        raise InputError(None, "--pose-noise", str(exc)) from None
    return {"gps_m": gps_m, "heading_deg": heading_deg, "height_m": height_m}


@app.command("contact-sheet")
def contact_sheet_command(
    dataset: Annotated[Path, typer.Argument(metavar="DATASET",
                                            help="Dataset folder (design.md layout).")],
    out: Annotated[Path, typer.Option(help="PNG to write.")] = Path("out/contact-sheet.png"),
    n: Annotated[int, typer.Option("--n", min=1, help="How many frames (the first N).")] = 8,
    columns: Annotated[int, typer.Option(min=1, help="Frame pairs per row.")] = 2,
    tile_width: Annotated[int, typer.Option(min=64, max=4096, help="Width of each tile, px.")] = 480,
    beside_real: Annotated[list[Path] | None, typer.Option(
        help="Real images (files or folders; repeatable): show each render beside one of them, "
        "cut to the render's aspect, instead of beside its class mask. Renders and real "
        "images are paired in order until either runs out.")] = None,
) -> None:
    """Tile frames with their class masks and the true clearance of every hull section, or
    renders beside real frames (--beside-real)."""
    from harborsight.viz.contact_sheet import contact_sheet, renders_beside_real

    stems = sorted(p.stem for p in (dataset / "frames").glob("*.json"))[:n]
    if not stems:
        err_console.print(f"error: {dataset / 'frames'}: no frames", markup=False)
        raise typer.Exit(2)
    if beside_real:
        from harborsight.perception.segment_images import collect_images

        real = collect_images(beside_real)
        if not real:
            err_console.print("error: --beside-real: no images found", markup=False)
            raise typer.Exit(2)
        sheet = renders_beside_real(dataset, stems, real[:n], tile_width)
    else:
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

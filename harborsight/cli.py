"""The ``harborsight`` command line: thin wrappers over the library."""

from __future__ import annotations

import json
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import Annotated

import cv2
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from harborsight.clearance.measure import ClearanceSettings
from harborsight.clearance.report import STATUS_OK
from harborsight.errors import HarborsightError, InputError
from harborsight.geometry.camera import load_camera_calibration
from harborsight.pipeline import (
    FrameJob,
    FrameOutcome,
    VesselCache,
    discover_jobs,
    measure_job,
    run_batch,
)
from harborsight.vessel.spec import load_vessel_spec

app = typer.Typer(
    add_completion=False, no_args_is_help=True,
    help="Per-section hull clearance of a vessel, measured from a companion drone's camera.",
)
console = Console()
err_console = Console(stderr=True, soft_wrap=True)


class Method(StrEnum):
    ground_plane = "ground_plane"
    gsd = "gsd"


def _fmt(value: float | None, digits: int) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def print_report_table(outcome: FrameOutcome) -> None:
    """Per-section table; adds the ground truth column when the frame carries one."""
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


def _settings(method: Method, sections: int | None, section_length_m: float | None,
              pose_margin_px: float) -> ClearanceSettings:
    return ClearanceSettings(method=method.value, pose_margin_px=pose_margin_px,
                             n_sections=sections, section_length_m=section_length_m)


def _run_folder(folder: Path, masks: Path | None, vessels: VesselCache,
                settings: ClearanceSettings, out: Path, camera, show_tables: bool) -> int:
    jobs = discover_jobs(folder, masks)
    with Progress(TextColumn("[bold]measuring"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True) as progress:
        task = progress.add_task("frames", total=len(jobs))
        outcomes = run_batch(jobs, vessels, settings, out, camera,
                             on_done=lambda _: progress.advance(task))
    good = [o for o in outcomes if o.error is None]
    bad = [o for o in outcomes if o.error is not None]
    if show_tables:
        for outcome in good:
            print_report_table(outcome)
    console.print(f"[green]{len(good)} frame(s) measured[/]; reports and overlays in {out}/")
    if bad:
        err_console.print(f"[red]{len(bad)} frame(s) skipped:[/]")
        for outcome in bad:
            err_console.print(f"  {outcome.job.stem}: {outcome.error}", markup=False)
    return 1 if bad and not good else 0


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
    out: Annotated[Path, typer.Option(help="Where reports (JSON) and overlays (PNG) go.")] = Path(
        "out/measure"),
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
        "error.")] = 2.0,
    tables: Annotated[bool, typer.Option(help="Print a table per frame.")] = True,
) -> None:
    """Measure hull clearance per section and write a report and an overlay per frame."""
    try:
        settings = _settings(method, sections, section_length_m, pose_margin_px)
        intrinsics = load_camera_calibration(camera) if camera else None
        vessels = VesselCache(load_vessel_spec(vessel) if vessel else None)
        if input_path.is_dir():
            raise typer.Exit(_run_folder(input_path, masks, vessels, settings, out, intrinsics,
                                         tables))
        meta_path = meta or input_path.with_suffix(".json")
        job = FrameJob(input_path.stem, meta_path, input_path, mask)
        outcome = measure_job(job, vessels, settings, out, intrinsics)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    if tables:
        print_report_table(outcome)
    console.print(f"report: {outcome.report_path}\noverlay: {outcome.overlay_path}")


def _bundled_samples() -> Path:
    return Path(str(resources.files("harborsight") / "data" / "samples"))


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Where the demo's reports and overlays go.")] = Path(
        "out/demo"),
    method: Annotated[Method, typer.Option(help="Distance method.")] = Method.ground_plane,
) -> None:
    """Measure the bundled sample frames and compare with their exact ground truth."""
    samples = _bundled_samples()
    console.print(f"[bold]harborsight demo[/]: {samples}\n"
                  "Samples are harbour frames rendered by harborsight's Blender simulator "
                  "(harborsight make-samples); masks are their exact labels.")
    settings = _settings(method, None, None, 2.0)
    code = _run_folder(samples, None, VesselCache(), settings, out, None, True)
    raise typer.Exit(code)


@app.command("make-samples")
def make_samples(
    out: Annotated[Path, typer.Option(help="Dataset folder to (re)write.")] = Path("out/samples"),
    seed: Annotated[int, typer.Option(help="Random seed of the layouts.")] = 20260501,
) -> None:
    """Regenerate the demo samples (Blender-rendered harbour frames with exact labels and
    ground truth; needs the sim extra)."""
    from harborsight.sim.samples import make_demo_samples

    stems = make_demo_samples(out, seed)
    console.print(f"wrote {len(stems)} frames to {out}/ "
                  f"({json.loads((out / 'dataset.json').read_text())['generator']})")


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
) -> None:
    """Render a synthetic harbour dataset with Blender: images, labels, instances, frame
    metadata with exact per-section ground truth (needs the sim extra: bpy)."""
    from harborsight.sim.dataset import SimulationConfig, parse_altitudes
    from harborsight.sim.dataset import simulate as run_sim

    try:
        config = SimulationConfig(
            seed=seed, preset=preset.value, altitudes_m=parse_altitudes(altitudes), camera=camera,
            max_tilt_deg=max_tilt_deg, vessel_spec=str(vessel.resolve()) if vessel else None,
            vessel_pool=vessel_pool, scenario=scenario, split=split)
        config.validate()
        with Progress(TextColumn("[bold]rendering"), BarColumn(), MofNCompleteColumn(),
                      TimeElapsedColumn(), TextColumn("{task.fields[status]}"),
                      console=console) as progress:
            task = progress.add_task("frames", total=n, status="")

            def on_frame(result) -> None:
                progress.advance(task)
                if result.error:
                    err_console.print(f"[red]frame {result.index:06d} failed:[/] {result.error}")
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
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), sheet)
    console.print(f"wrote {out} ({len(stems)} frames, {sheet.shape[1]}x{sheet.shape[0]} px)")


def main() -> None:
    try:
        app()
    except InputError as exc:  # pragma: no cover - commands catch their own
        err_console.print(f"error: {exc}", markup=False)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()

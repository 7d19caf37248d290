"""The ``demo`` command on the bundled samples, and ``make-samples`` that renders them."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Annotated

import typer

from harborsight.cli.app import (
    OWN_RIM_PX,
    POSE_MARGIN_PX,
    Method,
    app,
    clearance_settings,
    console,
    err_console,
    fmt_number,
    load_segmenter,
)
from harborsight.cli.measure import run_folder
from harborsight.cli.run import run_flight_with_progress
from harborsight.errors import HarborsightError
from harborsight.files import prepare_output_folder


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
        prepare_output_folder(out, "--out", inputs=(samples, samples / "flight"))
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

    settings = clearance_settings(method, None, None, POSE_MARGIN_PX, OWN_RIM_PX)
    code = run_folder(samples, None, VesselCache(), settings, out / "frames", None, True,
                       strict=True)
    flight = samples / "flight"
    console.print(f"\n[bold]flight[/]: {flight} (the tug berthing at "
                  f"{_flight_speed(flight)} m/s, 0.5 s between frames)")
    console.print("[bold]on the exact labels[/]")
    source = FolderSource(flight, flight / "labels", use_masks=True)
    summary = run_flight_with_progress(
        source, out / "flight", VesselCache(), None, RunOptions(settings=settings),
        {"input": str(flight), "masks": str(flight / "labels")})
    _print_demo_flight(flight, out / "flight", summary)
    failed = bool(summary.skipped)
    if default_model_path().is_file():
        console.print("\n[bold]on the default segmentation model[/]")
        segmenter = load_segmenter(None)
        summary = run_flight_with_progress(
            FolderSource(flight, use_masks=False), out / "flight-model", VesselCache(), segmenter,
            RunOptions(settings=settings), {"input": str(flight), "model": str(segmenter.path)})
        _print_demo_flight(flight, out / "flight-model", summary)
        failed = failed or bool(summary.skipped)
    else:
        console.print("\nno default segmentation model is packaged: the flight ran on labels only")
    return code or (1 if failed else 0)


def _print_demo_flight(flight: Path, out: Path, summary) -> None:
    """Frames measured, closest approach, distance error and measured-vs-true closing speed
    of a demo flight (:func:`~harborsight.evaluation.flight.score_flight`)."""
    from harborsight.evaluation.flight import score_flight

    md = summary.min_distance_m
    console.print(f"{summary.measured} of {summary.frames} frames measured; closest approach "
                  + (f"{md:.2f} m" if md is not None else "--"))
    try:
        (score,) = score_flight(flight, out / "sections.csv")
    except (HarborsightError, ValueError):
        score = None        # a flight without its ground truth, or of several scenes
    if score is not None and score.mae_m is not None:
        console.print(f"distance error against the ground truth from frame 3: MAE "
                      f"{score.mae_m:.3f} m per frame, {fmt_number(score.mae_filtered_m, 3)} m "
                      "filtered "
                      f"({score.estimates} sections)")
    if score is not None and score.closing is not None:
        comparison = score.closing
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

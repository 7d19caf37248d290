"""``harborsight dataset add-pose-noise``: noisy-sensor variants of a dataset's frames."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from harborsight.cli.app import console, err_console
from harborsight.cli.dataset import dataset_app
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_folder


@dataset_app.command("add-pose-noise")
def add_pose_noise_command(
    data: Annotated[Path, typer.Argument(help="Dataset with frames/*.json (e.g. from simulate).")],
    out: Annotated[Path, typer.Option(help="New dataset: noisy frames/, the rest linked.")],
    gps: Annotated[str, typer.Option(
        help="Horizontal RMS error of each receiver (drone and vessel): rtk (0.02 m), dgps "
        "(0.5 m), standalone (2 m), or metres.")] = "standalone",
    heading_deg: Annotated[float, typer.Option(
        min=0.0, max=180.0, help="One sigma of the drone's camera yaw and of the vessel's "
        "heading, degrees.")] = 2.0,
    height_m: Annotated[float, typer.Option(
        min=0.0, max=1000.0, help="One sigma of the drone's height above the water, metres.")] = 0.0,
    velocity_mps: Annotated[float, typer.Option(
        min=0.0, max=1000.0, help="One sigma per axis of the vessel's ground velocity (a GNSS "
        "receiver's Doppler velocity), m/s, where the frames give one (a flight's do).")] = 0.05,
    yaw_rate_deg_s: Annotated[float, typer.Option(
        min=0.0, max=180.0, help="One sigma of the vessel's rate of turn (a rate gyro), deg/s, "
        "where the frames give one (a flight's do).")] = 0.1,
    correlation_s: Annotated[float, typer.Option(
        min=0.0, max=1e6, help="Time constant of the errors' drift over the flight (a Gauss-Markov "
        "process over the frames in time order, each keeping its sigma); 0: independent per "
        "frame.")] = 0.0,
    seed: Annotated[int, typer.Option(min=0, max=2**32 - 1, help="Seed of the errors (per frame "
                                      "from this seed and the frame's name).")] = 0,
) -> None:
    """Write a copy of a dataset whose frames carry GPS, compass and height errors, the
    true pose kept in ground_truth.true_pose, for measuring what sensor noise does to
    the distances (evaluate distance --data OUT)."""
    from harborsight.sim.pose_noise import PoseNoise, parse_gps_noise, write_noisy_dataset

    try:
        try:
            gps_m = parse_gps_noise(gps)
        except ValueError as exc:
            raise InputError(None, "--gps", str(exc)) from None
        if not (data / "frames").is_dir():
            raise InputError(data, None, "not a dataset: no frames/ folder")
        prepare_output_folder(out, "--out", inputs=(data,))
        noise = PoseNoise(gps_m=gps_m, heading_deg=heading_deg, height_m=height_m,
                          correlation_s=correlation_s, velocity_mps=velocity_mps,
                          yaw_rate_deg_s=yaw_rate_deg_s)
        result = write_noisy_dataset(data, out, noise, seed)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False)
        raise typer.Exit(2) from None
    for line in result.skipped:
        err_console.print(f"skipped {line}", markup=False, highlight=False)
    console.print(f"{len(result.written)} frame(s) with sensor noise (GPS {gps_m:g} m per receiver, "
                  f"heading {heading_deg:g} deg, height {height_m:g} m, velocity "
                  f"{velocity_mps:g} m/s, rate of turn {yaw_rate_deg_s:g} deg/s"
                  + (f", drifting over {correlation_s:g} s" if correlation_s else "")
                  + f", seed {seed}) in {out}",
                  markup=False, highlight=False)
    if result.skipped:
        raise typer.Exit(1 if result.written else 2)

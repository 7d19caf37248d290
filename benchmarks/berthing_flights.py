"""Simulated berthing flights measured by `harborsight run` (issue #27's flight target).

Target: the default model with tracking, on simulated berthing flights, MAE at most 0.3 m up
to 100 m and the closing speed within 0.05 m/s. The bundled demo flight's harbour (the tug
alongside, seed 8: 48 frames at 2 Hz, the tug closing on the quay at 0.4 m/s from 8.7 m, for
41 of its frames) flown at 30, 60 and 100 m, rendered into WORK once (a re-run reuses the
frames; about 2.5 min a flight on this project's 2-core VM), each through `run` on its exact
labels and on the default model's masks, exact poses unless `--pose-noise` is given. Scored
by `harborsight evaluate flight` (every `ok` section with a true distance, from each
flight's fourth frame; the closest section's closing speed against the central difference
of its true distance). Prints a Markdown table with the target's ratio (target / actual: at
least 1 meets it) measured in this run. The frames give the vessel's velocity and rate of
turn, as the simulator writes them (with `--pose-noise`, perturbed at add-pose-noise's
defaults, 0.05 m/s and 0.1 deg/s); `--own-motion on,off` also measures without them.

    .venv/bin/python benchmarks/berthing_flights.py [--work /tmp/harborsight-flights]
        [--heights 30,60,100] [--pose-noise standalone,2,1] [--masks labels,model]
        [--segment-gsd-m default,0,0.11]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

from harborsight.evaluation.flight import FlightScore, score_flight
from harborsight.sim.dataset import simulate
from harborsight.sim.samples import FLIGHT_FRAMES, FLIGHT_SEED, flight_config, write_example_vessel

REPO = Path(__file__).resolve().parents[1]
HARBORSIGHT = [sys.executable, "-m", "harborsight.cli"]
TARGET_MAE_M = 0.3
TARGET_CLOSING_MPS = 0.05
TARGET_UP_TO_M = 100.0


def call(args: list[str]) -> None:
    """Run a harborsight command, its output shown; stop the benchmark when it fails."""
    print("$ harborsight " + " ".join(args), flush=True)
    subprocess.run(HARBORSIGHT + args, check=True, cwd=REPO)


def render_flight(out: Path, height_m: float, seed: int, workers: int) -> Path:
    """The demo flight's harbour (:func:`~harborsight.sim.samples.flight_config`) flown at
    ``height_m``, into ``out`` (resuming)."""
    write_example_vessel(out / "vessels")
    config = dataclasses.replace(flight_config(seed), altitudes_m=(height_m,))

    def say(result) -> None:
        if result.error:
            print(f"  frame {result.index}: {result.error}", flush=True)

    print(f"rendering the flight at {height_m:g} m into {out}", flush=True)
    summary = simulate(out, FLIGHT_FRAMES, config, workers=workers, on_frame=say)
    if summary.failed:
        raise SystemExit(f"{len(summary.failed)} frame(s) of {out} failed to render")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/harborsight-flights"))
    parser.add_argument("--pose-noise", default=None, metavar="GPS,HEADING_DEG,HEIGHT_M",
                        help="measure from noisy sensors (dataset add-pose-noise, seed 0)")
    parser.add_argument("--masks", default="labels,model", help="labels and/or model")
    parser.add_argument("--heights", default="30,60,100", help="flight heights, m")
    parser.add_argument("--segment-gsd-m", default="default", metavar="G[,G...]",
                        help="the model's masks at each of these `run --segment-gsd-m` (0: off; "
                        "default: run's own)")
    parser.add_argument("--own-motion", default="on", metavar="on|off|on,off",
                        help="measure with the frames' vessel velocity (run's default, on) "
                        "and/or without it (`run --no-own-motion`)")
    parser.add_argument("--seed", type=int, default=FLIGHT_SEED, help="the harbour's seed")
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    parser.add_argument("--json", type=Path, default=None, help="also write the scores here")
    args = parser.parse_args()
    work = args.work.resolve()
    flights = [render_flight(work / f"flight-{h}m", float(h), args.seed, args.workers)
               for h in args.heights.split(",")]
    for flight in flights:
        first = json.loads(next((flight / "frames").glob("*.json")).read_text())
        if "on" in args.own_motion.split(",") and "velocity_en_mps" not in first["vessel"]:
            print(f"warning: {flight} was rendered before flights gave the vessel's velocity: "
                  "its runs measure without own motion (render it again into a new --work)",
                  flush=True)
    if args.pose_noise:
        gps, heading_deg, height_m = args.pose_noise.split(",")
        noisy = []
        for flight in flights:
            out = work / "noisy" / flight.name
            if out.exists():
                shutil.rmtree(out)
            call(["dataset", "add-pose-noise", str(flight), "--out", str(out), "--gps", gps,
                  "--heading-deg", heading_deg, "--height-m", height_m])
            noisy.append(out)
        flights = noisy
    rows: list[tuple[str, FlightScore]] = []
    for flight in flights:
        for masks in args.masks.split(","):
            for gsd, own in ((g, o) for g in (args.segment_gsd_m.split(",") if masks == "model"
                                              else ["default"])
                             for o in args.own_motion.split(",")):
                name = (masks if gsd == "default" else f"{masks}@{gsd}") + (
                    ", no own motion" if own == "off" else "")
                out = work / "runs" / (f"{flight.name}{'-noisy' if args.pose_noise else ''}-"
                                       + name.replace(", no own motion", "-no-own-motion"))
                source = (["--masks", str(flight / "labels")] if masks == "labels"
                          else [] if gsd == "default" else ["--segment-gsd-m", gsd])
                call(["run", str(flight), *source, "--out", str(out), "--no-overlays",
                      "--no-video", *(["--no-own-motion"] if own == "off" else [])])
                rows += [(name, s) for s in score_flight(flight, out / "sections.csv")]
    print(f"\nberthing flights, {'noise ' + args.pose_noise if args.pose_noise else 'exact poses'};"
          f" target: the model's filtered MAE at most {TARGET_MAE_M} m up to "
          f"{TARGET_UP_TO_M:.0f} m, closing speed within {TARGET_CLOSING_MPS} m/s\n")
    print("| height | masks | sections | MAE per frame | MAE filtered | target/actual | "
          "closing speed (true) | its error (frames) | target/actual | shown while still "
          "(frames) | within 1σ | within 2σ | ≥ lower bound |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    rows.sort(key=lambda r: (r[1].altitude_m, r[0]))
    if args.json:
        args.json.write_text(json.dumps({
            "script": "benchmarks/berthing_flights.py", "machine": platform.machine(),
            "cpus": os.cpu_count(), "pose_noise": args.pose_noise, "seed": args.seed,
            "segment_gsd_m": args.segment_gsd_m, "own_motion": args.own_motion,
            "target_mae_m": TARGET_MAE_M, "target_closing_mps": TARGET_CLOSING_MPS,
            "rows": [{"masks": masks, **dataclasses.asdict(s)} for masks, s in rows]},
            indent=1, allow_nan=False) + "\n")
    for masks, s in rows:
        closing = s.closing
        print(f"| {s.altitude_m:.0f} m | {masks} | {s.estimates} | {_m(s.mae_m)} | "
              f"{_m(s.mae_filtered_m)} | {_ratio(TARGET_MAE_M, s.mae_filtered_m)} | "
              + ("— | — | — |" if closing is None else
                 f"{closing.measured_mps:.3f} ({closing.true_mps:.3f}) | "
                 f"{closing.median_abs_error_mps:.3f} ({closing.samples}) | "
                 f"{_ratio(TARGET_CLOSING_MPS, closing.median_abs_error_mps)} |")
              + (" — |" if s.still_speed_mps is None else
                 f" {s.still_speed_mps:.3f} ({s.still_frames}) |")
              + f" {_share(s.within_sigma_share)} | {_share(s.within_2_sigma_share)} |"
              f" {_share(s.lower_bound_share)} |")


def _m(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f} m"


def _ratio(target: float, actual: float | None) -> str:
    return "—" if actual is None else ("∞" if actual == 0 else f"{target / actual:.2f}x")


def _share(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.1f} %"


if __name__ == "__main__":
    main()

"""Simulated berthing flights measured by `harborsight run` (issue #27's flight target).

Target: the default model with tracking, on simulated berthing flights, MAE at most 0.3 m up
to 100 m and the closing speed within 0.05 m/s. Three flights of 48 frames at 2 Hz, the tug
closing on its nearest obstacle at 0.4 m/s: the bundled demo flight (60 m) and the two of
`simulate --n 96 --seed 3 --sequence-frames 48 --approach-speed-mps 0.4 --altitudes 30,100`
(30 m and 100 m; rendered into WORK once, a re-run reuses them), each through `run` on its
exact labels and on the default model's masks, exact poses unless `--pose-noise` is given.
Scored by `harborsight evaluate flight` (every `ok` section with a true distance, from each
flight's fourth frame; the closest section's closing speed against the central difference of
its true distance). Prints a Markdown table with the target's ratio (target / actual: at
least 1 meets it) measured in this run.

    .venv/bin/python benchmarks/berthing_flights.py [--work /tmp/harborsight-flights]
        [--pose-noise standalone,2,1] [--masks labels,model]

Rendering the two flights takes about 6 min on this project's 2-core VM (Blender), each run
with the model about a minute.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from harborsight.evaluation.flight import FlightScore, score_flight

REPO = Path(__file__).resolve().parents[1]
DEMO_FLIGHT = REPO / "harborsight" / "data" / "samples" / "flight"
HARBORSIGHT = [sys.executable, "-m", "harborsight.cli"]
TARGET_MAE_M = 0.3
TARGET_CLOSING_MPS = 0.05
TARGET_UP_TO_M = 100.0
RENDER = ["--n", "96", "--seed", "3", "--sequence-frames", "48", "--approach-speed-mps", "0.4",
          "--altitudes", "30,100"]


def call(args: list[str]) -> None:
    """Run a harborsight command, its output shown; stop the benchmark when it fails."""
    print("$ harborsight " + " ".join(args), flush=True)
    subprocess.run(HARBORSIGHT + args, check=True, cwd=REPO)


def split_by_scene(dataset: Path, out: Path) -> list[Path]:
    """One flight folder per scene of ``dataset`` (frame JSONs copied, images, labels and
    vessels linked), so that each is tracked on its own."""
    scenes: dict[int, list[Path]] = {}
    for path in sorted((dataset / "frames").glob("*.json")):
        scene = json.loads(path.read_text())["ground_truth"]["sequence"]["scene"]
        scenes.setdefault(int(scene), []).append(path)
    flights = []
    for scene, paths in sorted(scenes.items()):
        flight = out / f"scene-{scene}"
        if flight.exists():
            shutil.rmtree(flight)
        (flight / "frames").mkdir(parents=True)
        for name in ("images", "labels"):
            (flight / name).mkdir()
        for path in paths:
            shutil.copy2(path, flight / "frames" / path.name)
            image = json.loads(path.read_text())["image"]
            for name, file_name in (("images", image), ("labels", Path(image).stem + ".png")):
                os.symlink((dataset / name / file_name).resolve(), flight / name / file_name)
        shutil.copy2(dataset / "dataset.json", flight / "dataset.json")
        os.symlink((dataset / "vessels").resolve(), flight / "vessels")
        flights.append(flight)
    return flights


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/harborsight-flights"))
    parser.add_argument("--pose-noise", default=None, metavar="GPS,HEADING_DEG,HEIGHT_M",
                        help="measure from noisy sensors (dataset add-pose-noise, seed 0)")
    parser.add_argument("--masks", default="labels,model", help="labels and/or model")
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    args = parser.parse_args()
    work = args.work.resolve()
    rendered = work / "flights-30-100"
    call(["simulate", "--out", str(rendered), "--workers", str(args.workers), *RENDER])
    flights = [DEMO_FLIGHT, *split_by_scene(rendered, work / "split")]
    if args.pose_noise:
        gps, heading_deg, height_m = args.pose_noise.split(",")
        noisy = []
        for flight in flights:
            out = work / "noisy" / f"{flight.parent.name}-{flight.name}"
            if out.exists():
                shutil.rmtree(out)
            call(["dataset", "add-pose-noise", str(flight), "--out", str(out), "--gps", gps,
                  "--heading-deg", heading_deg, "--height-m", height_m])
            noisy.append(out)
        flights = noisy
    rows: list[tuple[str, FlightScore]] = []
    for flight in flights:
        for masks in args.masks.split(","):
            out = work / "runs" / f"{flight.parent.name}-{flight.name}-{masks}"
            source = ["--masks", str(flight / "labels")] if masks == "labels" else []
            call(["run", str(flight), *source, "--out", str(out), "--no-overlays", "--no-video"])
            rows += [(masks, s) for s in score_flight(flight, out / "sections.csv")]
    print(f"\nberthing flights, {'noise ' + args.pose_noise if args.pose_noise else 'exact poses'};"
          f" target: the model's filtered MAE at most {TARGET_MAE_M} m up to "
          f"{TARGET_UP_TO_M:.0f} m, closing speed within {TARGET_CLOSING_MPS} m/s\n")
    print("| height | masks | sections | MAE per frame | MAE filtered | target/actual | "
          "closing speed (true) | its error | target/actual | within 2σ | ≥ lower bound |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for masks, s in sorted(rows, key=lambda r: (r[1].altitude_m, r[0])):
        closing = s.closing
        print(f"| {s.altitude_m:.0f} m | {masks} | {s.estimates} | {_m(s.mae_m)} | "
              f"{_m(s.mae_filtered_m)} | {_ratio(TARGET_MAE_M, s.mae_filtered_m)} | "
              + ("— | — | — |" if closing is None else
                 f"{closing.measured_mps:.3f} ({closing.true_mps:.3f}) | "
                 f"{closing.median_abs_error_mps:.3f} | "
                 f"{_ratio(TARGET_CLOSING_MPS, closing.median_abs_error_mps)} |")
              + f" {_share(s.within_2_sigma_share)} | {_share(s.lower_bound_share)} |")


def _m(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f} m"


def _ratio(target: float, actual: float | None) -> str:
    return "—" if actual is None else ("∞" if actual == 0 else f"{target / actual:.2f}x")


def _share(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.1f} %"


if __name__ == "__main__":
    main()

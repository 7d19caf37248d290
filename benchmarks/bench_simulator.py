"""Seconds per frame of ``harborsight simulate`` at each preset, on this machine.

* cold: a fresh ``harborsight simulate --n 1`` process, wall clock, start-up included
  (Python, bpy import, Blender factory reset, vessel generation);
* warm: frames after the first in one process (what a long run costs per frame), from
  the in-process timings of each frame (render, ray-cast check, effects, PNG encoding).

Targets (issue 3): default (640x360) at most 4 s per frame on 2 cores; tiny at most 2 s
including start-up.

    .venv/bin/python benchmarks/bench_simulator.py [--frames 6] [--json out.json]
    .venv/bin/python benchmarks/bench_simulator.py --presets default --scenarios classic,lakeshore,marina

``--scenarios``: the warm time per frame of each scenario family (``classic``: the five
classic scenarios drawn as by default) in one run, and its ratio to the first one's (issue
#26: what the realistic families cost). A name ending in ``/full`` renders without the
out-of-view culling (``--no-cull-out-of-view``), e.g. ``--scenarios marina,marina/full``; one
ending in ``/sparse`` with the marinas and views of datasets before the thirty-second session
(``--no-dense-marinas --no-berth-views``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from harborsight.sim.dataset import SimulationConfig, simulate

TARGETS_S = {"tiny": 2.0, "default": 4.0}


def cold_start_seconds(preset: str, seed: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "harborsight.cli", "simulate", "--n", "1", "--out",
               str(Path(tmp) / "ds"), "--seed", str(seed), "--preset", preset]
        start = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        return time.perf_counter() - start


def warm_seconds(preset: str, n_frames: int, seed: int, scenario: str | None = None,
                 cull: bool = True, dense: bool = True) -> list[float]:
    with tempfile.TemporaryDirectory() as tmp:
        summary = simulate(Path(tmp) / "ds", n_frames,
                           SimulationConfig(seed=seed, preset=preset, scenario=scenario,
                                            cull_out_of_view=cull, dense_marinas=dense,
                                            berth_views=dense))
        return [r.seconds for r in sorted(summary.rendered, key=lambda r: r.index)]


def scenario_costs(preset: str, n_frames: int, seed: int, scenarios: list[str]) -> list[dict]:
    """Warm seconds per frame of each scenario family, interleaved in one run."""
    rows = []
    for name in scenarios:
        family, _, mode = name.partition("/")
        warm = warm_seconds(preset, n_frames + 1, seed, None if family == "classic" else family,
                            cull=mode != "full", dense=mode != "sparse")[1:]
        rows.append({"scenario": name, "warm_mean_s_per_frame": round(sum(warm) / len(warm), 2),
                     "warm_min_s": round(min(warm), 2), "warm_max_s": round(max(warm), 2),
                     "frames": len(warm)})
    base = rows[0]["warm_mean_s_per_frame"]
    for row in rows:
        row["ratio_to_first"] = round(row["warm_mean_s_per_frame"] / base, 2)
        print(f"{preset:8s} {row['scenario']:10s} warm {row['warm_mean_s_per_frame']:6.2f} s/frame "
              f"(min {row['warm_min_s']:.2f}, max {row['warm_max_s']:.2f}, {row['frames']} frames)   "
              f"x{row['ratio_to_first']:.2f} of {rows[0]['scenario']}")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--presets", default="tiny,default,high")
    parser.add_argument("--seed", type=int, default=404)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--scenarios", help="e.g. classic,lakeshore,marina: compare their cost")
    args = parser.parse_args()
    if args.scenarios:
        rows = [dict(r, preset=preset) for preset in args.presets.split(",")
                for r in scenario_costs(preset, args.frames, args.seed, args.scenarios.split(","))]
        if args.json:
            args.json.write_text(json.dumps({"machine": f"{platform.machine()}, {os.cpu_count()} cores",
                                             "rows": rows, "load_average_at_end": os.getloadavg()},
                                            indent=2) + "\n")
        return
    rows = []
    for preset in args.presets.split(","):
        n = args.frames if preset != "high" else max(2, args.frames // 3)
        cold = cold_start_seconds(preset, args.seed)
        warm = warm_seconds(preset, n, args.seed)[1:]  # the first frame is the cold one
        mean = sum(warm) / len(warm)
        target = TARGETS_S.get(preset)
        measured = cold if preset == "tiny" else mean
        rows.append({"preset": preset, "cold_start_1_frame_s": round(cold, 2),
                     "warm_mean_s_per_frame": round(mean, 2),
                     "warm_min_s": round(min(warm), 2), "warm_max_s": round(max(warm), 2),
                     "frames": len(warm), "target_s": target,
                     "target_met": None if target is None else measured <= target})
        print(f"{preset:8s} cold (1 frame, start-up incl.) {cold:6.2f} s   warm {mean:6.2f} s/frame "
              f"(min {min(warm):.2f}, max {max(warm):.2f}, {len(warm)} frames)"
              + ("" if target is None else f"   target {target:.0f} s: "
                 f"{'met' if measured <= target else f'missed by {measured / target - 1:.0%}'}"))
    result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "rows": rows,
              "load_average_at_end": os.getloadavg()}
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()

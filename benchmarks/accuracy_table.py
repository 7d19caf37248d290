"""Distance accuracy of ``ground_plane`` vs ``gsd`` on exact-geometry masks.

For each altitude and camera tilt, renders schematic scenes (seeded), measures every
section with both methods and compares with the shapely ground truth. Prints a Markdown
table of the absolute error in GSD pixels (nadir GSD at that altitude) and in metres.

    .venv/bin/python benchmarks/accuracy_table.py [--scenes 6]
"""

from __future__ import annotations

import argparse

import numpy as np

from harborsight.clearance import ClearanceSettings, measure_clearance
from harborsight.sim.schematic import flat_vessel, ground_truth, render, sample_scene
from harborsight.vessel.outline import outline_from_dimensions
from harborsight.vessel.spec import VesselSpec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6, help="scenes per altitude and tilt")
    args = parser.parse_args()
    outline = outline_from_dimensions(30.0, 10.0, 5.0, 5.0)
    vessel = flat_vessel(VesselSpec("test-boat", outline, np.zeros((0, 3)), 16))
    print("Absolute error per section in pixels of the nadir GSD at that altitude, and in metres.")
    print()
    print("| altitude m | tilt deg | sections | ground_plane p99 px | ground_plane max px "
          "| ground_plane MAE m | gsd p99 px | gsd max px | gsd MAE m |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for tilt in (0.0, 10.0, 15.0, 20.0):
        for altitude in (30, 60, 90, 120, 150):
            errors: dict[str, list[float]] = {"ground_plane": [], "gsd": []}
            metres: dict[str, list[float]] = {"ground_plane": [], "gsd": []}
            for i in range(args.scenes):
                rng = np.random.default_rng(1000 * altitude + 10 * int(tilt) + i)
                scene = sample_scene(vessel, rng, altitude_m=altitude, tilt_deg=tilt,
                                     scenario=("alongside", "slip", "open")[i % 3])
                _, labels, _ = render(scene)
                truth = ground_truth(scene)["sections"]
                for method in errors:
                    report = measure_clearance(labels, scene.geometry(), vessel,
                                               ClearanceSettings(method=method))
                    for s, t in zip(report.sections, truth, strict=True):
                        if s.status == "ok" and t["distance_m"] is not None and not s.contact:
                            err = s.distance_m - t["distance_m"]
                            errors[method].append(abs(err) / report.gsd_m_per_px)
                            metres[method].append(abs(err))
            n = len(errors["ground_plane"])
            gp, gs = np.array(errors["ground_plane"]), np.array(errors["gsd"])
            print(f"| {altitude} | {tilt:.0f} | {n} | {np.percentile(gp, 99):.2f} | {gp.max():.2f} "
                  f"| {np.mean(metres['ground_plane']):.3f} | {np.percentile(gs, 99):.2f} "
                  f"| {gs.max():.2f} | {np.mean(metres['gsd']):.3f} |")


if __name__ == "__main__":
    main()

"""Clearance step (label mask -> report) on 640x360 masks, one core.

Targets: at most 2 ms per frame without pose refinement (issue #2), at most 5 ms with it,
from a pose 2.3 m and 2.5 degrees off (issue #27), also when the mask comes from a model and
its probabilities widen the sigmas (a stand-in: logits from the labels blurred by 1.5 px).
The last configuration adds the vessel's velocity and rate of turn (each section's own rate,
clearance.own_motion). Prints the median time per frame for each scene and configuration,
and its ratio to the target, measured in one run.

    .venv/bin/python benchmarks/bench_clearance.py [--repeats 300]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from harborsight.clearance import ClearanceSettings, measure_clearance
from harborsight.clearance.pose_refinement import PoseRefinementSettings, corrected_geometry
from harborsight.clearance.uncertainty import FrameVelocities
from harborsight.perception.confidence import SolidConfidence
from harborsight.sim.schematic import render, sample_scene
from harborsight.vessel.spec import load_vessel_spec

TARGET_MS = 2.0
REFINED_TARGET_MS = 5.0
SENSOR_ERROR = np.array([1.8, -1.5, np.radians(2.5)])      # GPS east/north m, heading rad
SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"


def model_like_confidence(labels: np.ndarray) -> SolidConfidence:
    """Probabilities shaped like a model's: one-hot labels (ignore as solid) blurred by
    1.5 px, times 6, as logits on the frame's own grid."""
    classes = np.where(labels == 255, 2, labels)
    one_hot = np.stack([cv2.GaussianBlur((classes == k).astype(np.float32), (0, 0), 1.5)
                        for k in range(3)])
    return SolidConfidence(6.0 * one_hot, labels.shape[1], labels.shape[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    vessel = load_vessel_spec(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml")
    print(f"clearance step, 640x360, one core, median of {args.repeats} runs; target "
          f"{TARGET_MS} ms, {REFINED_TARGET_MS} ms with pose refinement")
    print(f"{'scene':<22}{'configuration':<34}{'contour px':>11}{'ms/frame':>10}{'target/actual':>15}")
    fixed = PoseRefinementSettings(enabled=False)
    for scenario, altitude, tilt in [("alongside", 40, 0), ("slip", 60, 10), ("touching", 45, 5),
                                     ("open", 120, 0)]:
        scene = sample_scene(vessel, np.random.default_rng(11), altitude_m=altitude, tilt_deg=tilt,
                             scenario=scenario)
        _, labels, _ = render(scene)
        geometry = scene.geometry()
        contour_px = sum(len(c) for c in cv2.findContours(
            (labels != 0).astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)[0])
        configurations = [
            (f"{method}, exact pose", geometry, ClearanceSettings(method=method, pose_refinement=fixed),
             TARGET_MS) for method in ("ground_plane", "gsd")]
        configurations = [(*c, None, None) for c in configurations]
        off_pose = corrected_geometry(geometry, SENSOR_ERROR)
        configurations.append(("ground_plane, refined from 2.3 m off", off_pose,
                               ClearanceSettings(), REFINED_TARGET_MS, None, None))
        configurations.append(("  and the model's doubt", off_pose, ClearanceSettings(),
                               REFINED_TARGET_MS, model_like_confidence(labels), None))
        configurations.append(("  and the vessel's velocity", off_pose, ClearanceSettings(),
                               REFINED_TARGET_MS, model_like_confidence(labels),
                               FrameVelocities(None, (0.3, -0.2), 0.05, 0.5, 0.1)))
        for name_of, frame_geometry, settings, target, confidence, velocities in configurations:
            for _ in range(10):
                measure_clearance(labels, frame_geometry, vessel, settings, confidence=confidence,
                                  velocities=velocities)
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                measure_clearance(labels, frame_geometry, vessel, settings, confidence=confidence,
                                  velocities=velocities)
                times.append(time.perf_counter() - t0)
            ms = 1000 * float(np.median(times))
            name = f"{scenario} {altitude} m {tilt} deg"
            print(f"{name:<22}{name_of:<34}{contour_px:>11}{ms:>10.2f}{target / ms:>14.2f}x")


if __name__ == "__main__":
    main()

"""Distance error against sensor noise, with and without pose refinement (issue #27, item 4).

For each noise level (GPS class of both receivers, compass sigma of drone and vessel,
height sigma) a noisy copy of a simulator dataset is written (``dataset add-pose-noise``),
every frame is measured with and without pose refinement, and the median and mean absolute
per-section errors per altitude band, their 95th percentile, the share of sections within
0.5 m and the calibration of the reported sigmas (truth within ``distance ± 2 sigma_m``, truth
at or above ``distance_lower_m``; target 90-98 % and at least 95 %) are printed as Markdown,
beside the noise-free ones.

    .venv/bin/python benchmarks/sensor_noise_study.py --data /work/data/bench260 \\
        --work /tmp/noise-study [--model default] [--levels standalone:2:0,dgps:1:0]

``--levels`` are ``GPS:HEADING_DEG:HEIGHT_M`` (GPS: rtk, dgps, standalone or metres).
Exact labels unless ``--model`` is given. Results also go to ``WORK/study.json``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from harborsight.clearance.measure import ClearanceSettings
from harborsight.clearance.pose_refinement import PoseRefinementSettings
from harborsight.evaluation.distance import evaluate_frames, load_frames, model_masks, oracle_masks
from harborsight.sim.pose_noise import PoseNoise, parse_gps_noise, write_noisy_dataset

DEFAULT_LEVELS = ("rtk:0.2:0", "dgps:1:0", "standalone:1:0", "standalone:2:0", "standalone:3:0",
                  "standalone:2:1")
BANDS = ((30, 50), (60, 100), (110, 150))


def band_stats(results, low: float, high: float) -> tuple[float, ...]:
    """Median, mean, 95th percentile of the absolute error (m), the share of sections within
    0.5 m, within two reported sigmas and at or above the lower bound (%), and how many
    sections, for frames flown from ``low`` to ``high`` metres."""
    band = [r for r in results if r.kind == "estimate" and low <= r.altitude_m <= high]
    if not band:
        return (float("nan"),) * 6 + (0,)
    errors = np.array([r.abs_error_m for r in band])
    # frames whose pose the image contradicts are left out of the calibration shares
    within = [w for r in band if (w := r.within_sigmas(2.0)) is not None]
    above = [a for r in band if (a := r.lower_bound_holds) is not None]
    return (float(np.median(errors)), float(np.mean(errors)), float(np.percentile(errors, 95)),
            float(100.0 * np.mean(errors <= 0.5)),
            float(100.0 * np.mean(within)) if within else float("nan"),
            float(100.0 * np.mean(above)) if above else float("nan"), int(errors.size))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--model", default=None, help="ONNX model, or 'default'")
    parser.add_argument("--levels", default=",".join(DEFAULT_LEVELS))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    masks_name, masks = "oracle", oracle_masks
    if args.model:
        from harborsight.perception.default_model import load_default_segmenter

        segmenter = load_default_segmenter(None if args.model == "default" else Path(args.model))
        cache: dict[str, tuple] = {}
        segment = model_masks(segmenter.segment_with_confidence)

        def masks(dataset: Path, frame: dict) -> tuple:   # same images in every copy
            if frame["image"] not in cache:
                cache[frame["image"]] = segment(dataset, frame)
            return cache[frame["image"]]
        masks_name = "model"

    on = ClearanceSettings()
    off = replace(on, pose_refinement=PoseRefinementSettings(enabled=False))
    rows = []
    frames = load_frames(args.data)
    exact = evaluate_frames(args.data, frames, masks_name, masks, "ground_plane", clearance=on)
    rows.append(("exact sensors", "on", [band_stats(exact, *b) for b in BANDS]))
    for level in args.levels.split(","):
        gps, heading, height = level.split(":")
        noise = PoseNoise(parse_gps_noise(gps), float(heading), float(height))
        noisy_dir = args.work / level.replace(":", "_")
        if not (noisy_dir / "frames").is_dir():
            write_noisy_dataset(args.data, noisy_dir, noise, args.seed)
        noisy_frames = load_frames(noisy_dir)
        name = f"GPS {noise.gps_m:g} m, heading {noise.heading_deg:g} deg, height {noise.height_m:g} m"
        for label, settings in (("off", off), ("on", on)):
            results = evaluate_frames(noisy_dir, noisy_frames, masks_name, masks, "ground_plane",
                                      clearance=settings)
            rows.append((name, label, [band_stats(results, *b) for b in BANDS]))
        print(f"done: {name}", flush=True)

    head = " | ".join(f"{lo}-{hi} m median / MAE / p95 / ≤0.5 m / ±2σ / ≥lower" for lo, hi in BANDS)
    print(f"\n{masks_name} masks, {len(frames)} frames of {args.data}\n")
    print(f"| sensors | refinement | {head} |")
    print("|---|---|" + "---:|" * len(BANDS))
    for name, label, stats in rows:
        cells = " | ".join(f"{m:.2f} / {a:.2f} / {p:.2f} / {w:.0f} % / {c:.1f} % / {b:.1f} %"
                           for m, a, p, w, c, b, _ in stats)
        print(f"| {name} | {label} | {cells} |")
    args.work.mkdir(parents=True, exist_ok=True)
    (args.work / "study.json").write_text(json.dumps(
        [{"sensors": n, "refinement": r, "bands": [
            {"altitude_m": list(b), "median_m": m, "mae_m": a, "p95_m": p, "within_0_5_m_pct": w,
             "within_2_sigma_pct": c, "truth_at_or_above_lower_pct": lb, "n": k}
            for b, (m, a, p, w, c, lb, k) in zip(BANDS, s, strict=True)]} for n, r, s in rows],
        indent=1))


if __name__ == "__main__":
    main()

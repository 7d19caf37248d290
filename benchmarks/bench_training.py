"""Training iterations per second of the real training loop (data, augmentation, SGD step).

Writes a small schematic dataset at 640x360 (or uses ``--data``), then for each network and
crop runs ``harborsight.training.loop.train`` for ``--warmup + --iterations`` steps and times
the last ``--iterations`` from the log's ``elapsed_s``. Also times the bare optimiser step on
random tensors (no data pipeline) so the two costs can be told apart.

    .venv/bin/python benchmarks/bench_training.py [--networks ...] [--crops 360 256] [--batch 8]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import create_network
from harborsight.sim.schematic import sample_scene, write_frame
from harborsight.training.config import DEFAULT_AUX_WEIGHTS, TrainConfig
from harborsight.training.loop import train
from harborsight.training.losses import bootstrapped_cross_entropy
from harborsight.vessel.outline import outline_from_dimensions
from harborsight.vessel.spec import VesselSpec


def write_dataset(root: Path, frames: int, seed: int = 0) -> Path:
    outline = outline_from_dimensions(30.0, 10.0, 5.0, 5.0)
    vessel = VesselSpec("bench-boat", outline, np.column_stack((outline, np.zeros(len(outline)))), 16)
    rng = np.random.default_rng(seed)
    split = {}
    for i in range(frames):
        scene = sample_scene(vessel, rng, altitude_m=float(rng.uniform(30, 100)),
                             tilt_deg=float(rng.uniform(0, 15)))
        write_frame(scene, root, f"{i:06d}")
        split[f"{i:06d}"] = "train"
    (root / "dataset.json").write_text(json.dumps({"split": split}))
    return root


def bare_step_rate(name: str, batch: int, crop: int, warmup: int, iterations: int) -> float:
    """Optimiser steps per second on random uint8 images, loss as in the loop (keep 100 %)."""
    torch.manual_seed(0)
    model = SegmentationModel(create_network(name, 3, aux_heads=True)).train()
    optimizer = torch.optim.SGD(model.parameters(), lr=0.01, momentum=0.9)
    images = torch.randint(0, 256, (batch, crop, crop, 3), dtype=torch.uint8)
    target = torch.randint(0, 3, (batch, crop, crop))
    weights = DEFAULT_AUX_WEIGHTS[name]

    def step() -> None:
        out = model(images)
        main, aux = out if isinstance(out, tuple) else (out, [])
        loss = bootstrapped_cross_entropy(main, target, 1.0) + sum(
            w * bootstrapped_cross_entropy(a, target, 1.0) for w, a in zip(weights, aux, strict=True))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    for _ in range(warmup):
        step()
    start = time.perf_counter()
    for _ in range(iterations):
        step()
    return iterations / (time.perf_counter() - start)


def loop_rate(name: str, data: Path, out: Path, batch: int, crop: int, warmup: int,
              iterations: int, workers: int) -> float:
    config = TrainConfig(model=name, data_dirs=[str(data)], out_dir=str(out), batch_size=batch,
                         crop_hw=(crop, crop), iterations=10000, val_every=0,
                         checkpoint_every=10**9, num_workers=workers, device="cpu")
    train(config, until_iteration=warmup + iterations, show_progress=False)
    lines = [json.loads(x) for x in (out / "train_log.jsonl").read_text().splitlines()]
    t = {line["iteration"]: line["elapsed_s"] for line in lines}
    return iterations / (t[warmup + iterations] - t[warmup])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", nargs="+", default=["ddrnet23_slim", "bisenetv2"])
    parser.add_argument("--crops", nargs="+", type=int, default=[360, 256])
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--workers", type=int, default=0, help="DataLoader workers (0: in-process)")
    parser.add_argument("--threads", type=int, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--data", type=Path, help="dataset folder (default: 16 schematic frames)")
    parser.add_argument("--json", type=Path, help="write the rows here")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or write_dataset(Path(tmp) / "data", 16)
        for name in args.networks:
            for crop in args.crops:
                row = {"network": name, "batch": args.batch, "crop": f"{crop}x{crop}",
                       "threads": torch.get_num_threads(), "workers": args.workers}
                row["loop_it_per_s"] = loop_rate(name, data, Path(tmp) / f"run-{name}-{crop}",
                                                 args.batch, crop, args.warmup, args.iterations,
                                                 args.workers)
                row["bare_step_it_per_s"] = bare_step_rate(name, args.batch, crop, args.warmup,
                                                           args.iterations)
                row["hours_per_10k_iterations"] = 10000 / row["loop_it_per_s"] / 3600
                print(json.dumps(row), flush=True)
                rows.append(row)
    print()
    print("| network | batch | crop | threads | loop it/s | bare step it/s | hours / 10k it |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['network']} | {r['batch']} | {r['crop']} | {r['threads']} | {r['loop_it_per_s']:.3f} "
              f"| {r['bare_step_it_per_s']:.3f} | {r['hours_per_10k_iterations']:.1f} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()

"""Frames per second of each network at 640x360: torch eager, ONNX Runtime fp32 and int8.

Measured side by side in one run (issue #4 targets: ONNX Runtime at least 1.4x torch eager;
DDRNet-23-slim at least 20 FPS fp32 on the 2-core CPU). With ``--device cuda`` it times torch
on the GPU instead (fp32 and fp16 autocast), for machines that have one.

    .venv/bin/python benchmarks/bench_segmentation.py [--networks ...] [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from harborsight.perception.networks import NETWORKS, create_network, inference_parameter_count

HEIGHT, WIDTH = 360, 640


def _rate(fn, seconds: float, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    count, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds or count < 3:
        fn()
        count += 1
    return count / (time.perf_counter() - start)


def bench_cpu(name: str, seconds: float, threads: int) -> dict:
    from harborsight.perception.export import export_onnx
    from harborsight.perception.model import SegmentationModel
    from harborsight.perception.onnx_segmenter import OnnxSegmenter
    from harborsight.perception.quantization import quantize_int8

    torch.set_num_threads(threads)
    model = SegmentationModel(create_network(name, 3, aux_heads=False)).eval()
    image = np.random.default_rng(0).integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    batch = torch.from_numpy(image[None])
    row = {"network": name, "params": inference_parameter_count(model.network)}
    with torch.inference_mode():
        row["torch_fps"] = _rate(lambda: model(batch), seconds)
    with tempfile.TemporaryDirectory() as tmp:
        fp32 = export_onnx(model, Path(tmp) / "m.onnx", HEIGHT, WIDTH)
        calib = np.random.default_rng(1).integers(0, 255, (4, HEIGHT, WIDTH, 3), dtype=np.uint8)
        int8 = quantize_int8(fp32, Path(tmp) / "m8.onnx", calib)
        for key, path in (("ort_fp32_fps", fp32), ("ort_int8_fps", int8)):
            # the session harborsight runs: on CPUs whose uint8 x int8 sums saturate, the
            # int8 weights as uint8 (perception.onnx_segmenter)
            segmenter = OnnxSegmenter(path, threads=threads)
            feed = {"image": image[None]}
            row[key] = _rate(lambda s=segmenter.session, f=feed: s.run(["logits"], f), seconds)
        row["int8_arithmetic"] = segmenter.int8_arithmetic()
    row["ort_vs_torch"] = row["ort_fp32_fps"] / row["torch_fps"]
    return row


def bench_cuda(name: str, seconds: float) -> dict:
    from harborsight.perception.model import SegmentationModel

    model = SegmentationModel(create_network(name, 3, aux_heads=False)).eval().cuda()
    batch = torch.randint(0, 255, (1, HEIGHT, WIDTH, 3), dtype=torch.uint8, device="cuda")
    row = {"network": name, "params": inference_parameter_count(model.network),
           "gpu": torch.cuda.get_device_name()}

    def step(fp16: bool):
        with torch.inference_mode(), torch.autocast("cuda", torch.float16, enabled=fp16):
            model(batch)
        torch.cuda.synchronize()

    row["cuda_fp32_fps"] = _rate(lambda: step(False), seconds, warmup=10)
    row["cuda_fp16_fps"] = _rate(lambda: step(True), seconds, warmup=10)

    # training iterations per second: batch 8, SGD, fp16 autocast, aux heads on
    train = SegmentationModel(create_network(name, 3, aux_heads=True)).train().cuda()
    optimiser = torch.optim.SGD(train.parameters(), lr=0.01, momentum=0.9)
    scaler = torch.amp.GradScaler("cuda")
    images = torch.randint(0, 255, (8, HEIGHT, WIDTH, 3), dtype=torch.uint8, device="cuda")
    target = torch.randint(0, 3, (8, HEIGHT, WIDTH), device="cuda")

    def train_step():
        optimiser.zero_grad(set_to_none=True)
        with torch.autocast("cuda", torch.float16):
            out = train(images)
            main, aux = out if isinstance(out, tuple) else (out, [])
            loss = torch.nn.functional.cross_entropy(main, target) + sum(
                torch.nn.functional.cross_entropy(a, target) for a in aux)
        scaler.scale(loss).backward()
        scaler.step(optimiser)
        scaler.update()
        torch.cuda.synchronize()

    row["cuda_train_it_per_s_batch8"] = _rate(train_step, seconds, warmup=5)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", nargs="*", default=list(NETWORKS))
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()
    rows = []
    for name in args.networks:
        row = bench_cuda(name, args.seconds) if args.device == "cuda" else bench_cpu(
            name, args.seconds, args.threads)
        rows.append(row)
        print(json.dumps({k: round(v, 2) if isinstance(v, float) else v for k, v in row.items()}),
              flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()

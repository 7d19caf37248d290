"""The default int8 model three ways on this CPU: speed and labels, measured in one run.

1. a plain ONNX Runtime session of the shipped file (int8 weights, fused uint8 x int8 kernels:
   on x86 without VNNI their 16-bit pair sums saturate);
2. :class:`OnnxSegmenter` as ``segment``, ``measure`` and ``run`` use it (the same, except
   that on such CPUs the weights are given as uint8, whose kernels do not saturate);
3. the graph as written (``--exact-int8``: dequantise, float convolution, quantise).

Prints the milliseconds per 640x360 frame of each and its ratio to 1, and the share of
pixels whose label differs from 3 on the committed real frames (marina orthophotos and
lake-shore photos, resized to the model's input), per set: mean and worst frame.

    .venv/bin/python benchmarks/bench_int8_arithmetic.py [--frames 40] [--threads 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from harborsight.perception.default_model import default_model_path
from harborsight.perception.onnx_segmenter import OnnxSegmenter, cpu_int8_dot_product

REAL = Path(__file__).resolve().parents[1] / "data" / "real"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="real frames per set")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    path = default_model_path()
    options = ort.SessionOptions()
    options.intra_op_num_threads = args.threads
    deployed = OnnxSegmenter(path, threads=args.threads)
    sessions = {
        "plain ONNX Runtime, int8 weights": ort.InferenceSession(
            str(path), options, providers=["CPUExecutionProvider"]),
        f"OnnxSegmenter: {deployed.int8_arithmetic()}": deployed.session,
        "as written (--exact-int8)": OnnxSegmenter(
            path, threads=args.threads, reference_arithmetic=True).session,
    }
    names = list(sessions)
    print(f"default model, CPU int8 dot product: {cpu_int8_dot_product()}, "
          f"{args.threads} thread(s)")

    frame = deployed.fit(cv2.imread(sorted((REAL / "marina" / "images").iterdir())[0].as_posix()))
    times: dict[str, list[float]] = {name: [] for name in names}
    for _ in range(3):
        for session in sessions.values():
            session.run(["logits"], {"image": frame[None]})
    for _ in range(args.repeats):          # interleaved, so that the machine's noise is shared
        for name, session in sessions.items():
            start = time.perf_counter()
            session.run(["logits"], {"image": frame[None]})
            times[name].append(time.perf_counter() - start)
    base_ms = 1000 * float(np.median(times[names[0]]))
    print(f"{'session':<58}{'ms/frame':>9}{'x plain':>9}")
    for name in names:
        ms = 1000 * float(np.median(times[name]))
        print(f"{name:<58}{ms:>9.1f}{ms / base_ms:>9.2f}")

    print(f"\nlabels differing from the graph as written, {args.frames} frames a set "
          "(mean / worst frame)")
    for folder in ("marina", "lakeshore"):
        files = sorted((REAL / folder / "images").iterdir())
        picked = [files[i] for i in np.linspace(0, len(files) - 1, args.frames).astype(int)]
        differing = {name: [] for name in names[:2]}
        for file in dict.fromkeys(picked):
            image = deployed.fit(cv2.imread(file.as_posix()))[None]
            exact = sessions[names[2]].run(["logits"], {"image": image})[0][0].argmax(0)
            for name in names[:2]:
                labels = sessions[name].run(["logits"], {"image": image})[0][0].argmax(0)
                differing[name].append(float((labels != exact).mean()))
        for name, shares in differing.items():
            print(f"{folder:<10}{name:<58}{100 * np.mean(shares):6.2f} % / "
                  f"{100 * np.max(shares):5.2f} %")


if __name__ == "__main__":
    main()

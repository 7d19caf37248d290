"""Segmentation mIoU with test-time augmentation: mirror and input-scale averaging.

Runs a training checkpoint on every ``--step``-th frame of a dataset split at each input
scale ``s`` (the frame resized bilinearly by ``s``, its logits resized back), with and without
the mirror image, and scores each combination. A combination averages the softmax of its
passes and takes the argmax:

    p(x) = 1/K sum_k softmax(f(T_k x)) mapped back by T_k^-1,   labels = argmax_c p_c

Prints mIoU and per-class IoU per combination (fp32 torch; the shipped graph runs one pass).

    .venv/bin/python benchmarks/tta_segmentation.py --checkpoint RUN/last.pt --data BENCH
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from harborsight.evaluation.segmentation import SegmentationScores, confusion_matrix
from harborsight.perception.classes import CLASS_NAMES, NUM_CLASSES
from harborsight.training.checkpoint import load_checkpoint, model_from_checkpoint
from harborsight.training.dataset import SegmentationFrames

#: name -> passes (input scale, mirrored)
COMBINATIONS = {
    "x1": [(1.0, False)],
    "x1.25": [(1.25, False)],
    "x1.5": [(1.5, False)],
    "x1 + mirror": [(1.0, False), (1.0, True)],
    "x1 + x1.5": [(1.0, False), (1.5, False)],
}


def softmax_at_frame_size(model, image_bgr: np.ndarray, scale: float, mirrored: bool
                          ) -> torch.Tensor:
    """Class probabilities (C, H, W) of one pass, in the frame's own pixel grid."""
    h, w = image_bgr.shape[:2]
    image = image_bgr[:, ::-1] if mirrored else image_bgr
    if scale != 1.0:
        image = cv2.resize(image, (round(w * scale), round(h * scale)),
                           interpolation=cv2.INTER_LINEAR)
    logits = model(torch.from_numpy(np.ascontiguousarray(image))[None])
    if scale != 1.0:
        logits = F.interpolate(logits, (h, w), mode="bilinear", align_corners=False)
    probabilities = logits.softmax(1)[0]
    return probabilities.flip(-1) if mirrored else probabilities


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="harborsight train checkpoint (.pt)")
    parser.add_argument("--data", required=True, action="append", help="dataset folder(s)")
    parser.add_argument("--split", default="test")
    parser.add_argument("--step", type=int, default=4, help="score every STEP-th frame")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = model_from_checkpoint(load_checkpoint(args.checkpoint)).eval()
    frames = SegmentationFrames(args.data, [args.split])
    indices = range(0, len(frames), args.step)
    passes = sorted({p for combo in COMBINATIONS.values() for p in combo})
    confusion = {name: np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64) for name in COMBINATIONS}
    start = time.perf_counter()
    with torch.inference_mode():
        for n, i in enumerate(indices):
            image, labels = frames[i]
            probabilities = {p: softmax_at_frame_size(model, image, *p) for p in passes}
            for name, combo in COMBINATIONS.items():
                predicted = sum(probabilities[p] for p in combo).argmax(0).numpy()
                confusion[name] += confusion_matrix(labels, predicted.astype(np.uint8))
            if n % 50 == 0:
                print(f"frame {n + 1}/{len(indices)}, {time.perf_counter() - start:.0f} s",
                      flush=True)
    print(f"\n{len(indices)} frames of {', '.join(args.data)} ({args.split}), "
          f"checkpoint {args.checkpoint}\n")
    print("| passes | mIoU | " + " | ".join(f"IoU {c}" for c in CLASS_NAMES) + " |")
    print("|---|---:|" + "---:|" * NUM_CLASSES)
    for name, matrix in confusion.items():
        scores = SegmentationScores(matrix)
        ious = " | ".join(f"{100 * x:.2f}" for x in scores.iou)
        print(f"| {name} | {100 * scores.miou:.2f} | {ious} |")


if __name__ == "__main__":
    main()

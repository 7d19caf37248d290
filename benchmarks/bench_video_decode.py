"""What naming damaged video frames costs: ``flight.video_decode.read_video_frames`` (PyAV,
packet by packet, slice threads, the packets' times read first) against OpenCV's reader
(what ``run`` used before) and PyAV's plain decoding, on clips built here.

Prints milliseconds per frame and the ratios measured in one run (this machine is shared:
compare ratios, not times across runs).

    .venv/bin/python benchmarks/bench_video_decode.py [--frames 60] [--size 1920x1080]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def _clip(path: Path, codec: str, frames: int, width: int, height: int) -> None:
    import av

    rng = np.random.default_rng(0)
    texture = rng.integers(0, 255, (height, width * 2, 3), np.uint8)
    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=30)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = ({"preset": "veryfast", "g": "30"} if codec == "libx264"
                          else {"x265-params": "keyint=30:log-level=0", "preset": "veryfast"})
        for k in range(frames):
            picture = np.ascontiguousarray(texture[:, 4 * k:4 * k + width])
            for packet in stream.encode(av.VideoFrame.from_ndarray(picture, format="bgr24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def _ms_per_frame(read) -> float:
    start = time.perf_counter()
    count = read()
    return 1000.0 * (time.perf_counter() - start) / max(count, 1)


def main() -> None:
    import av
    import cv2

    from harborsight.flight.video_decode import read_video_frames

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--size", default="1920x1080")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))

    def plain(path: Path):
        def read() -> int:
            with av.open(str(path)) as container:
                return sum(1 for f in container.decode(video=0) if f.to_ndarray(format="bgr24") is not None)
        return read

    def opencv(path: Path):
        def read() -> int:
            capture, count = cv2.VideoCapture(str(path)), 0
            while capture.read()[0]:
                count += 1
            capture.release()
            return count
        return read

    def named(path: Path):
        return lambda: sum(1 for _ in read_video_frames(path))

    print(f"{args.frames} frames of {width}x{height}, ms per frame (decode and convert to BGR)")
    print()
    print("| codec | read_video_frames | OpenCV | PyAV plain | vs OpenCV | vs PyAV plain |")
    print("|---|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as folder:
        for codec in ("libx264", "libx265"):
            path = Path(folder) / f"{codec}.mp4"
            _clip(path, codec, args.frames, width, height)
            ours, theirs, base = (_ms_per_frame(f(path)) for f in (named, opencv, plain))
            print(f"| {codec} | {ours:.1f} | {theirs:.1f} | {base:.1f} | {ours / theirs:.2f} "
                  f"| {ours / base:.2f} |")


if __name__ == "__main__":
    main()

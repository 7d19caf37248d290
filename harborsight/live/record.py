"""``live --record DIR``: what the live aid saw and said, written as it goes.

* ``states.jsonl``: every published ``harborsight.live/1`` state, one per line, flushed;
* ``images/NNNNNN.jpg`` and ``frames/NNNNNN.json``: each measured frame and its metadata (a
  ``harborsight.frame/1`` file naming the image, ``vessel_spec`` made absolute), so the
  folder is a flight that ``harborsight run DIR`` replays frame by frame.

Every file is whole when written (the frame's JSON after its image), so a killed process
leaves a readable record of everything up to its last frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from harborsight.files import write_bytes_atomic, write_text_atomic
from harborsight.frame import FrameMetadata

#: JPEG quality of the recorded frames
JPEG_QUALITY = 92


class SessionRecorder:
    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        (self.folder / "images").mkdir(parents=True, exist_ok=True)
        (self.folder / "frames").mkdir(exist_ok=True)
        self._states = (self.folder / "states.jsonl").open("w", encoding="utf-8")
        self.frames = 0

    def state(self, state: dict) -> None:
        self._states.write(json.dumps(state) + "\n")
        self._states.flush()

    def frame(self, image: np.ndarray, meta: FrameMetadata, meta_path: Path | None) -> None:
        """Save a measured frame and its metadata as the next frame of the record."""
        stem = f"{self.frames:06d}"
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            return
        write_bytes_atomic(self.folder / "images" / f"{stem}.jpg", jpeg.tobytes())
        record = meta.to_dict()
        record["image"] = f"{stem}.jpg"
        spec = record.get("vessel_spec")
        if isinstance(spec, str) and meta_path is not None and not Path(spec).is_absolute():
            record["vessel_spec"] = str((Path(meta_path).parent / spec).resolve())
        write_text_atomic(self.folder / "frames" / f"{stem}.json", json.dumps(record, indent=1) + "\n")
        self.frames += 1

    def close(self) -> None:
        self._states.close()

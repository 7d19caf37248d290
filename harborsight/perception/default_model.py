"""The segmentation model ``measure`` uses when no masks are given (deployed path: no torch).

The default model is ``harborsight/data/models/default.onnx`` with its sidecar
``default.json`` (written by ``harborsight export``, completed by
``scripts/ship_default_model.py`` with the held-out scores and the commands that rebuild it).
Without one, :func:`load_default_segmenter` says how to make one.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from harborsight.errors import InputError
from harborsight.perception.classes import CLASS_NAMES
from harborsight.perception.onnx_segmenter import OnnxSegmenter


def default_model_path() -> Path:
    """Where the packaged default model lives (it may not exist)."""
    return Path(str(resources.files("harborsight") / "data" / "models" / "default.onnx"))


def load_onnx_segmenter(path: str | Path, threads: int | None = None) -> OnnxSegmenter:
    """An :class:`OnnxSegmenter` with its sidecar (``model.json`` beside ``model.onnx``, if any)
    as ``.sidecar``; refuses a model whose classes are not harborsight's."""
    path = Path(path)
    segmenter = OnnxSegmenter(path, threads=threads)
    sidecar_file = path.with_suffix(".json")
    segmenter.sidecar = {}
    if sidecar_file.is_file():
        try:
            segmenter.sidecar = json.loads(sidecar_file.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(sidecar_file, None, f"invalid JSON: {exc}") from None
    classes = segmenter.sidecar.get("classes") or segmenter.metadata.get("classes")
    if classes is not None:
        names = list(classes.values()) if isinstance(classes, dict) else list(classes)
        if names != list(CLASS_NAMES):
            raise InputError(sidecar_file if segmenter.sidecar else path, "classes",
                             f"model classes {names} differ from harborsight's {list(CLASS_NAMES)}")
    return segmenter


def load_default_segmenter(path: str | Path | None = None) -> OnnxSegmenter:
    """The default model (or the one at ``path``), or an error saying how to get one."""
    path = Path(path) if path is not None else default_model_path()
    if not path.is_file():
        raise InputError(path, None, "no segmentation model here. "
                         "Pass label masks (--mask / --masks), or train one (harborsight train), "
                         "export it (harborsight export) and pass --model MODEL.onnx")
    return load_onnx_segmenter(path)


def describe(segmenter: OnnxSegmenter) -> str:
    """One line on what a model is and how good it is on held-out frames (from its sidecar),
    with a warning when it is below the accuracy a default model is meant to have."""
    sidecar = segmenter.sidecar
    network = sidecar.get("network") or segmenter.metadata.get("network")
    parts = [str(segmenter.path)]
    if network:
        parts.append(f"({', '.join(filter(None, (network, sidecar.get('precision'))))})")
    heldout = sidecar.get("heldout")
    if heldout:
        parts.append(f"held-out mIoU {100 * heldout['miou']:.1f} % on {heldout['frames']} "
                     "synthetic frames")
        if sidecar.get("meets_target") is False:
            parts.append(f"[below the {100 * sidecar['target_miou']:.0f} % target: "
                         "treat its distances as indicative]")
    return " ".join(parts)

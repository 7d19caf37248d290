"""The segmentation model ``measure`` uses when no masks are given (deployed path: no torch).

The default model is ``harborsight/data/models/default.onnx`` with its sidecar
``default.json`` (written by ``harborsight export``, completed by
``scripts/ship_default_model.py`` with the held-out scores and the commands that rebuild it).
Without one, :func:`load_default_segmenter` says how to make one.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from harborsight.errors import InputError
from harborsight.perception.classes import CLASS_NAMES
from harborsight.perception.onnx_segmenter import OnnxSegmenter
from harborsight.text_formats import parse_json_text


def default_model_path() -> Path:
    """Where the packaged default model lives (it may not exist)."""
    return Path(str(resources.files("harborsight") / "data" / "models" / "default.onnx"))


def load_onnx_segmenter(path: str | Path, threads: int | None = None,
                        reference_arithmetic: bool = False) -> OnnxSegmenter:
    """An :class:`OnnxSegmenter` with its sidecar (``model.json`` beside ``model.onnx``, if any)
    as ``.sidecar``; refuses a model whose classes are not harborsight's.

    ``harborsight export --int8`` writes one sidecar for both files: ``model.int8.onnx``
    takes ``model.json`` when that names it as ``onnx_int8``, with ``precision`` int8 and
    no held-out block (those scores are the fp32 graph's). ``reference_arithmetic``: see
    :class:`OnnxSegmenter`."""
    path = Path(path)
    segmenter = OnnxSegmenter(path, threads=threads, reference_arithmetic=reference_arithmetic)
    sidecar_file = path.with_suffix(".json")
    segmenter.sidecar = {}
    if sidecar_file.is_file():
        segmenter.sidecar = _read_sidecar(sidecar_file)
    elif path.name.endswith(".int8.onnx"):
        fp32_sidecar = path.with_name(path.name[:-len(".int8.onnx")] + ".json")
        if fp32_sidecar.is_file():
            shared = _read_sidecar(fp32_sidecar)
            if shared.get("onnx_int8") == path.name:
                sidecar_file = fp32_sidecar
                segmenter.sidecar = {**shared, "precision": "int8", "heldout": None}
    classes = segmenter.sidecar.get("classes") or segmenter.metadata.get("classes")
    if classes is not None:
        names = list(classes.values()) if isinstance(classes, dict) else list(classes)
        if names != list(CLASS_NAMES):
            raise InputError(sidecar_file if segmenter.sidecar else path, "classes",
                             f"model classes {names} differ from harborsight's {list(CLASS_NAMES)}")
    return segmenter


def _read_sidecar(path: Path) -> dict:
    try:
        return parse_json_text(path.read_text(), path)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, None, f"cannot read: {exc}") from None


def load_default_segmenter(path: str | Path | None = None, reference_arithmetic: bool = False
                           ) -> OnnxSegmenter:
    """The default model (or the one at ``path``), or an error saying how to get one."""
    path = Path(path) if path is not None else default_model_path()
    if not path.is_file():
        raise InputError(path, None, "no segmentation model here. "
                         "Pass label masks (--mask / --masks), or train one (harborsight train), "
                         "export it (harborsight export) and pass --model MODEL.onnx")
    return load_onnx_segmenter(path, reference_arithmetic=reference_arithmetic)


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
        parts.append(f"held-out mIoU {100 * heldout['miou']:.2f} % on {heldout['frames']} "
                     "synthetic frames")
        if sidecar.get("meets_target") is False:
            parts.append(f"[below the {100 * sidecar['target_miou']:g} % target: "
                         "treat its distances as indicative]")
    return " ".join(parts)

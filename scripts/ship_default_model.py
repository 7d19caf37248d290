"""Install an exported model as the packaged default (harborsight/data/models/default.onnx).

Usage::

    python scripts/ship_default_model.py RUN/model.onnx --heldout SEG.json [--int8] \
        --reproduce STEPS.txt [--target-miou 0.95] [--real SEG.json ...]

* ``RUN/model.onnx`` and its sidecar ``RUN/model.json`` come from ``harborsight export``;
  ``--int8`` ships the quantised copy the sidecar names instead of the fp32 graph.
* ``SEG.json`` is ``harborsight evaluate segmentation --json`` of *that same file* on held-out
  frames; its mIoU, per-class IoU, FPS and per-height mIoU go into ``default.json``.
* ``--real SEG.json`` (repeatable): the same file evaluated on a real val split
  (``evaluate segmentation --mode auto``); each goes into ``default.json``'s ``real_val``.
* ``STEPS.txt`` holds the commands that rebuild the model from nothing, one per line
  (simulate, train, ..., export), recorded verbatim.

The sidecar's machine-specific paths are kept as provenance; ``meets_target`` says whether
the held-out mIoU reaches the bar issue #4 sets for a default model, and the CLI says so
whenever the default model is used.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parent.parent / "harborsight" / "data" / "models"


def _split_scores(evaluation: dict, shipped_file: Path) -> tuple[str, dict]:
    """(split, scores) of an ``evaluate segmentation`` JSON of one split, which must be an
    evaluation of the file being shipped."""
    if Path(evaluation["model"]).resolve() != shipped_file.resolve():
        sys.exit(f"error: {evaluation['model']} was evaluated, but {shipped_file} is shipped")
    (split, scores), = evaluation["splits"].items()
    return split, scores


def heldout_summary(evaluation: dict, shipped_file: Path) -> dict:
    """The held-out block of ``default.json`` from an ``evaluate segmentation`` JSON."""
    split, scores = _split_scores(evaluation, shipped_file)
    return {
        "data": evaluation["data"], "split": split, "frames": scores["frames"],
        "miou": scores["miou"], "mean_accuracy": scores["mean_accuracy"], "iou": scores["iou"],
        "fps_2_threads": evaluation["fps"],
        "miou_by_height_m": {f"{b['height_m']:g}": b["miou"] for b in scores.get("by_height_m", [])},
        "command": f"harborsight evaluate segmentation --model MODEL --data "
                   f"{' --data '.join(evaluation['data'])} --threads 2",
    }


def real_summary(evaluation: dict, shipped_file: Path) -> dict:
    """One ``real_val`` entry of ``default.json``: scores of the shipped file on a real split."""
    split, scores = _split_scores(evaluation, shipped_file)
    return {"data": evaluation["data"], "split": split, "frames": scores["frames"],
            "mode": evaluation.get("mode"), "miou": scores["miou"], "iou": scores["iou"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", type=Path, help="model.onnx written by harborsight export")
    parser.add_argument("--heldout", type=Path, required=True,
                        help="evaluate segmentation --json of the shipped file")
    parser.add_argument("--reproduce", type=Path, required=True,
                        help="text file: the commands that rebuild the model, one per line")
    parser.add_argument("--int8", action="store_true", help="ship the int8 copy")
    parser.add_argument("--real", type=Path, action="append", default=[],
                        help="evaluate segmentation --json of the shipped file on a real val split")
    parser.add_argument("--target-miou", type=float, default=0.95)
    args = parser.parse_args()

    sidecar = json.loads(args.model.with_suffix(".json").read_text())
    name = sidecar["onnx_int8"] if args.int8 else sidecar["onnx"]
    if name is None:
        sys.exit(f"error: {args.model.with_suffix('.json')}: onnx_int8: no int8 copy exported")
    shipped_file = args.model.parent / name
    heldout = heldout_summary(json.loads(args.heldout.read_text()), shipped_file)
    steps = [line.strip() for line in args.reproduce.read_text().splitlines() if line.strip()]

    MODELS_DIR.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(shipped_file, MODELS_DIR / "default.onnx")
    sidecar.update({
        "onnx": "default.onnx", "onnx_int8": None,
        "precision": "int8" if args.int8 else "fp32",
        "heldout": heldout,
        "real_val": [real_summary(json.loads(path.read_text()), shipped_file) for path in args.real],
        "target_miou": args.target_miou,
        "meets_target": heldout["miou"] >= args.target_miou,
        "reproduce": steps,
    })
    (MODELS_DIR / "default.json").write_text(json.dumps(sidecar, indent=2) + "\n")
    size_mb = (MODELS_DIR / "default.onnx").stat().st_size / 1e6
    print(f"shipped {shipped_file} as {MODELS_DIR / 'default.onnx'} ({size_mb:.1f} MB); "
          f"held-out mIoU {100 * heldout['miou']:.1f} % on {heldout['frames']} frames "
          f"({'meets' if sidecar['meets_target'] else 'below'} the "
          f"{100 * args.target_miou:g} % target)")


if __name__ == "__main__":
    main()

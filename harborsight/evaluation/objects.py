"""Which objects does a segmenter see? Per-object recall from the simulator's instance masks.

Pixel-averaged scores (mIoU) barely register a fender or a buoy of a few dozen pixels, but a
missed fender is a hull-to-obstacle gap read up to a metre too wide. So each object ``k`` of a
frame (``instances/<stem>.png``; 0 water, 1 the vessel of interest, 65535 no hit, all left
out) is scored on its own:

    solid recall_k = |{p in k : predicted(p) != water}| / |k|      (any solid class counts:
                                                                    the distance needs solid)
    detected_k     = solid recall_k >= 0.5
    contrast_k     = |mean grey(k) - mean grey(water within 3 px of k)|   (0-255 grey levels)

and summarised per kind of object (quay, fender, buoy, ...; from the simulator's scene,
rebuilt from the dataset's seed) and per visible size in pixels.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.perception.classes import WATER

#: visible-size bins in pixels (lower edges); the last bin is open
AREA_BINS_PX = (0, 20, 80, 300)
#: contrast bins in grey levels (lower edges)
CONTRAST_BINS_GREY = (0, 10, 25)
DETECTED_RECALL = 0.5
_RING_PX = 3


@dataclass
class ObjectRecall:
    frame: str
    kind: str
    area_px: int
    solid_recall: float
    contrast_grey: float        # NaN where no water borders the object


def object_recalls(frame: str, image_bgr: np.ndarray, labels: np.ndarray,
                   predicted: np.ndarray, instances: np.ndarray,
                   kinds: dict[int, str] | None = None) -> list[ObjectRecall]:
    """Every object of one frame with its solid recall and contrast (module docstring);
    ``kinds`` maps instance id -> kind (``object`` where unknown)."""
    from harborsight.sim.scene import NO_HIT, VESSEL_INSTANCE

    skipped = {0, VESSEL_INSTANCE, NO_HIT}   # water, the vessel itself, no hit
    grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY).astype(np.float64)
    water = labels == WATER
    kernel = np.ones((2 * _RING_PX + 1, 2 * _RING_PX + 1), np.uint8)
    rows = []
    ids, counts = np.unique(instances, return_counts=True)
    for instance_id, area in zip(ids.tolist(), counts.tolist(), strict=True):
        if instance_id in skipped:
            continue
        mask = instances == instance_id
        ring = cv2.dilate(mask.astype(np.uint8), kernel).astype(bool) & water & ~mask
        contrast = abs(grey[mask].mean() - grey[ring].mean()) if ring.any() else float("nan")
        recall = float(np.mean(predicted[mask] != WATER))
        rows.append(ObjectRecall(frame, (kinds or {}).get(instance_id, "object"), int(area),
                                 recall, float(contrast)))
    return rows


def simulator_kinds(dataset_dir: Path) -> Callable[[str], dict[int, str]] | None:
    """``kinds(stem) -> {instance id: kind}`` from the simulator's scene of each frame (rebuilt
    from the dataset's seed, no bpy), or None when the dataset is not a simulator one."""
    meta = dataset_dir / "dataset.json"
    try:
        doc = json.loads(meta.read_text())
    except (OSError, ValueError):
        return None
    if "parameters" not in doc or not (dataset_dir / "vessels").is_dir():
        return None
    from harborsight.evaluation.distance import scene_planner

    plan = scene_planner(dataset_dir)

    def kinds(stem: str) -> dict[int, str]:
        frame = json.loads((dataset_dir / "frames" / f"{stem}.json").read_text())
        scene, _ = plan(frame)
        return {o.instance_id: o.kind for o in scene.objects}
    return kinds


@dataclass
class ObjectSummary:
    kind: str
    n: int
    median_area_px: float
    mean_solid_recall: float
    detected_share: float
    #: per AREA_BINS_PX lower edge: (objects, detected share)
    by_area: dict[int, tuple[int, float]]
    #: per CONTRAST_BINS_GREY lower edge: (objects, detected share)
    by_contrast: dict[int, tuple[int, float]]


def _binned(rows: list[ObjectRecall], edges: Sequence[float], value: Callable[[ObjectRecall], float]
            ) -> dict[int, tuple[int, float]]:
    out = {}
    for i, lower in enumerate(edges):
        upper = edges[i + 1] if i + 1 < len(edges) else float("inf")
        chosen = [r for r in rows if lower <= value(r) < upper]
        if chosen:
            out[int(lower)] = (len(chosen), float(np.mean([r.solid_recall >= DETECTED_RECALL
                                                           for r in chosen])))
    return out


def summarise_objects(rows: list[ObjectRecall]) -> list[ObjectSummary]:
    """Per kind (most objects first), then ``all``."""
    groups: dict[str, list[ObjectRecall]] = {}
    for r in rows:
        groups.setdefault(r.kind, []).append(r)
    ordered = sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0]))
    if len(ordered) > 1:
        ordered.append(("all", rows))
    out = []
    for kind, group in ordered:
        recall = np.array([r.solid_recall for r in group])
        out.append(ObjectSummary(
            kind, len(group), float(np.median([r.area_px for r in group])),
            float(recall.mean()), float(np.mean(recall >= DETECTED_RECALL)),
            _binned(group, AREA_BINS_PX, lambda r: r.area_px),
            _binned([r for r in group if np.isfinite(r.contrast_grey)], CONTRAST_BINS_GREY,
                    lambda r: r.contrast_grey)))
    return out


def _bin_label(edges: Sequence[float], i: int, unit: str) -> str:
    if i + 1 < len(edges):
        return f"{edges[i]:g}–{edges[i + 1]:g} {unit}"
    return f"≥ {edges[i]:g} {unit}"


def markdown_object_table(rows: list[ObjectSummary]) -> str:
    """Per kind: objects, median size, mean solid recall, share detected, and the share
    detected per size and per contrast bin (objects in brackets)."""
    area_heads = [_bin_label(AREA_BINS_PX, i, "px") for i in range(len(AREA_BINS_PX))]
    contrast_heads = [_bin_label(CONTRAST_BINS_GREY, i, "grey")
                      for i in range(len(CONTRAST_BINS_GREY))]
    lines = ["| object | n | median size px | mean solid recall | detected | "
             + " | ".join(f"detected, {h}" for h in area_heads + contrast_heads) + " |",
             "|---|---:|---:|---:|---:|" + "---:|" * (len(area_heads) + len(contrast_heads))]

    def cell(bins: dict[int, tuple[int, float]], lower: float) -> str:
        if int(lower) not in bins:
            return "—"
        n, share = bins[int(lower)]
        return f"{100 * share:.0f} % ({n})"

    for r in rows:
        cells = [cell(r.by_area, e) for e in AREA_BINS_PX]
        cells += [cell(r.by_contrast, e) for e in CONTRAST_BINS_GREY]
        lines.append(f"| {r.kind} | {r.n} | {r.median_area_px:.0f} | "
                     f"{100 * r.mean_solid_recall:.0f} % | {100 * r.detected_share:.0f} % | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"

"""A contact sheet of a dataset: each frame beside its class mask, with the ground truth of
every hull section drawn on the image (coloured by clearance, distance in metres)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from harborsight.frame import FrameGeometry, parse_frame_metadata
from harborsight.vessel.spec import load_vessel_spec
from harborsight.viz.overlay import BLACK, WHITE, section_colour

#: BGR colours of the classes: water, ship, obstacle; ignore is black
CLASS_BGR = {0: (150, 90, 20), 1: (60, 60, 220), 2: (160, 160, 160), 255: (0, 0, 0)}


def colourise_labels(labels: np.ndarray) -> np.ndarray:
    out = np.zeros((*labels.shape, 3), np.uint8)
    for cls, bgr in CLASS_BGR.items():
        out[labels == cls] = bgr
    return out


def draw_ground_truth(image: np.ndarray, frame_doc: dict, dataset_dir: Path) -> np.ndarray:
    """Sections of the frame's vessel projected from its metadata, coloured by true clearance."""
    out = image.copy()
    meta = parse_frame_metadata(frame_doc, source=None, base_dir=dataset_dir)
    geometry = FrameGeometry.from_metadata(meta)
    vessel = load_vessel_spec(dataset_dir / frame_doc["vessel_spec"])
    truth = frame_doc.get("ground_truth", {}).get("sections", [])
    outline = vessel.sections(len(truth) or None)
    scale = max(0.3, min(image.shape[:2]) / 900.0)
    centre = geometry.camera.project(geometry.vessel_to_enu(vessel.outline.mean(axis=0)[None]))[0][0]
    for k in range(outline.n_sections):
        uv, front = geometry.camera.project(geometry.vessel_to_enu(outline.section_polyline(k)))
        if not front.all():
            continue
        d = truth[k].get("distance_m") if k < len(truth) else None
        colour = section_colour(d, 5.0, 2.0)
        cv2.polylines(out, [np.round(uv).astype(np.int32)], False, colour, 2, cv2.LINE_AA)
        mid = uv[len(uv) // 2] if len(uv) > 2 else uv.mean(axis=0)
        direction = mid - centre
        direction /= max(np.linalg.norm(direction), 1e-9)
        text = "??" if d is None else f"{d:.1f}"
        pos = mid + direction * 14
        (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        x, y = int(pos[0] - w / 2), int(pos[1] + h / 2)
        cv2.putText(out, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, BLACK, 3, cv2.LINE_AA)
        cv2.putText(out, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, WHITE, 1, cv2.LINE_AA)
    return out


def contact_sheet(dataset_dir: Path, stems: list[str] | None = None, columns: int = 2,
                  tile_width: int = 480) -> np.ndarray:
    """Tile ``[image + ground truth | class mask]`` pairs, ``columns`` pairs per row."""
    frames_dir = dataset_dir / "frames"
    stems = stems or sorted(p.stem for p in frames_dir.glob("*.json"))
    if not stems:
        raise FileNotFoundError(f"{frames_dir}: no frames")
    tiles = []
    for stem in stems:
        doc = json.loads((frames_dir / f"{stem}.json").read_text())
        image = cv2.imread(str(dataset_dir / "images" / doc["image"]), cv2.IMREAD_COLOR)
        labels = cv2.imread(str(dataset_dir / "labels" / f"{Path(doc['image']).stem}.png"),
                            cv2.IMREAD_UNCHANGED)
        if image is None or labels is None:
            raise FileNotFoundError(f"{dataset_dir}: image or label of frame {stem} missing")
        height = round(tile_width * image.shape[0] / image.shape[1])
        big = cv2.resize(image, (tile_width, height), interpolation=cv2.INTER_AREA)
        # draw at tile size: scale the intrinsics in the frame document
        sx = tile_width / image.shape[1]
        doc_scaled = json.loads(json.dumps(doc))
        cam = doc_scaled["camera"]
        for key in ("fx", "fy"):
            cam[key] *= sx
        cam["cx"] = (cam["cx"] + 0.5) * sx - 0.5
        cam["cy"] = (cam["cy"] + 0.5) * sx - 0.5
        cam["width"], cam["height"] = tile_width, height
        left = draw_ground_truth(big, doc_scaled, dataset_dir)
        sim = doc.get("simulation", {})
        alt = doc.get("uav", {}).get("alt_m", 0.0)
        caption = f"{stem}  {doc.get('ground_truth', {}).get('scenario', '')}  {alt:.0f} m"
        if "label_agreement" in sim:
            caption += f"  labels/ray-cast {100 * sim['label_agreement']:.2f}%"
        cv2.putText(left, caption, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, BLACK, 3, cv2.LINE_AA)
        cv2.putText(left, caption, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, WHITE, 1, cv2.LINE_AA)
        mask = cv2.resize(colourise_labels(labels), (tile_width, height),
                          interpolation=cv2.INTER_NEAREST)
        tiles.append(np.hstack((left, mask)))
    h, w = tiles[0].shape[:2]
    gap = 4
    columns = min(columns, len(tiles))
    rows = []
    for r in range(0, len(tiles), columns):
        row = tiles[r:r + columns]
        row += [np.zeros_like(tiles[0])] * (columns - len(row))
        parts = []
        for t in row:
            parts += [t, np.full((h, gap, 3), 255, np.uint8)]
        rows += [np.hstack(parts[:-1]), np.full((gap, columns * w + (columns - 1) * gap, 3), 255,
                                                np.uint8)]
    return np.vstack(rows[:-1])


def _cover(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """``image`` scaled to cover ``width`` x ``height`` and cut to it around its centre (a
    4:3 photo or a square tile shown in a 16:9 tile without stretching)."""
    scale = max(width / image.shape[1], height / image.shape[0])
    big = cv2.resize(image, (max(width, round(image.shape[1] * scale)),
                             max(height, round(image.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    y0, x0 = (big.shape[0] - height) // 2, (big.shape[1] - width) // 2
    return big[y0:y0 + height, x0:x0 + width]


def renders_beside_real(dataset_dir: Path, stems: list[str], real_images: list[Path],
                        tile_width: int = 480) -> np.ndarray:
    """Rows of ``[render | real frame]``: the simulator's images beside real ones at the
    same tile size (real frames cut to the render's aspect, never stretched), captioned
    with the render's scenario and height and the real file's name."""
    if not stems or not real_images:
        raise FileNotFoundError(f"{dataset_dir}: need renders and real images")
    rows = []
    for stem, real_path in zip(stems, real_images, strict=False):
        doc = json.loads((dataset_dir / "frames" / f"{stem}.json").read_text())
        render = cv2.imread(str(dataset_dir / "images" / doc["image"]), cv2.IMREAD_COLOR)
        real = cv2.imread(str(real_path), cv2.IMREAD_COLOR)
        if render is None or real is None:
            raise FileNotFoundError(f"cannot read {dataset_dir / 'images' / doc['image']} or {real_path}")
        height = round(tile_width * render.shape[0] / render.shape[1])
        left = cv2.resize(render, (tile_width, height), interpolation=cv2.INTER_AREA)
        right = _cover(real, tile_width, height)
        captions = (f"render {stem}  {doc.get('ground_truth', {}).get('scenario', '')}  "
                    f"{doc.get('uav', {}).get('alt_m', 0.0):.0f} m", f"real {real_path.name}")
        for tile, caption in zip((left, right), captions, strict=True):
            cv2.putText(tile, caption, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, BLACK, 3, cv2.LINE_AA)
            cv2.putText(tile, caption, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, WHITE, 1, cv2.LINE_AA)
        rows += [np.hstack((left, np.full((height, 4, 3), 255, np.uint8), right)),
                 np.full((4, 2 * tile_width + 4, 3), 255, np.uint8)]
    return np.vstack(rows[:-1])

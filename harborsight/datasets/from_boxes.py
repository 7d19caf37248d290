"""Label masks from boxes plus image evidence (``harborsight dataset label-from-boxes``).

Box datasets (YOLO, Roboflow) say where the boats, docks and cars are but not which pixels
are water. A mask is built in three steps, all at a working size whose long side is
``work_long_side_px`` (the texture scales below are in pixels of that size):

1. **Water.** Open water is smooth at the scale of a few pixels while foliage, lawns, roofs,
   rip-rap and boats are not, whatever the light: the texture measure is

       t = G_σ2 * |L − G_σ1 * L| · 1.5      (L: CIELAB lightness, G_σ: Gaussian blur)

   with σ1 = 1.5 px and σ2 = 4 px, which a single step edge (a shadow line on the water)
   barely raises but dense leaf texture does. The largest smooth region outside the boxes
   seeds the water; smooth regions of the same chroma, or darker and bluer (water in the
   shade of trees), that lie near the seed join it. GrabCut then separates water from solid
   on the features (texture, blurred a*, blurred b*), so that shadowed water (dark but
   smooth) stays water; only textured pixels greener than the water are held as certainly
   solid, so that glint (textured, not green) is left for GrabCut to decide. Water regions neither
   connected to the seed nor large are dropped (a smooth roof is not a lake), and a second
   GrabCut pass on the colour image moves the water line onto the image edge inside a
   narrow band around it.
2. **Solid.** Everything that is not water is ``obstacle``. Each box of a ship class is cut
   out on the image at full resolution, upsampled ``vessel_upsample`` times (a jetski is
   a dozen pixels wide in a 2048-px photo): GrabCut from the box (inside: probably the
   vessel; outside: not), with the pixels of the box darker than the water around it by
   ``shadow_darker_l`` and nearly grey (CIELAB chroma under ``shadow_max_chroma``) seeded
   as probably not, since a boat's shadow on the water is its most vessel-like
   neighbour. The largest piece is kept, filled to its convex hull (seen from above a
   hull is convex; this closes dark seats and biminis that GrabCut left out at its edge),
   less one ring of upsampled pixels (GrabCut takes the interpolated edge, half a pixel
   out), and becomes ``ship``; the solid pixels of the box outside it (a dock's corner, or a
   part of the boat GrabCut missed) become 255. Boxes mapped to ``ignore`` make their
   non-water pixels 255.
3. **Doubt.** Small solid islands in the water that no box explains (an unlabelled boat, a
   buoy, a wake) become 255, as does the part of a boxed island outside its boxes (the
   wake behind a boat), and so does a band of ``ignore_band_px`` pixels on each side of
   every class boundary, where a labeller could not be sure either.

The result is a proposal for review, not ground truth: :func:`review_sheet` draws masks
beside their images so that every one can be checked by eye.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from harborsight.perception.classes import IGNORE

WATER, SHIP, OBSTACLE = 0, 1, 2


@dataclass(frozen=True)
class BoxLabelSettings:
    """Tuning of :func:`label_from_boxes`; lengths in pixels of the working size."""

    work_long_side_px: int = 1024
    smooth_texture: float = 4.0        # t below this: smooth (a water seed candidate)
    probable_water_texture: float = 6.0
    solid_texture: float = 12.0        # t above this and far from the water's chroma: solid
    seed_chroma_distance: float = 6.0  # a*b* distance of a smooth region that joins the seed
    island_max_fraction: float = 0.003  # unexplained islands up to this share of the frame: 255
    ignore_band_px: int = 1
    grabcut_iterations: int = 4
    vessel_upsample: float = 2.0       # the vessel cut's scale on the full-resolution image
    vessel_iterations: int = 6
    shadow_darker_l: float = 8.0       # L* below the water's by this: perhaps the shadow
    shadow_max_chroma: float = 25.0


@dataclass
class BoxLabelResult:
    """Labels at the image's own size, and what was decided on the way."""

    labels: np.ndarray
    water_fraction: float
    notes: list[str] = field(default_factory=list)


def _texture(lightness: np.ndarray) -> np.ndarray:
    """Local contrast relative to local brightness (leaves in shade stay textured)."""
    high_pass = np.abs(lightness - cv2.GaussianBlur(lightness, (0, 0), 1.5))
    relative = high_pass / (cv2.GaussianBlur(lightness, (0, 0), 4.0) + 20.0) * 150.0
    return cv2.GaussianBlur(relative, (0, 0), 4.0) * 1.5


def _disk(radius_px: float) -> np.ndarray:
    size = max(1, round(2 * radius_px) | 1)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def _box_raster(shape_hw: tuple[int, int], boxes: Sequence, scale: float,
                classes: set[int] | None = None) -> np.ndarray:
    raster = np.zeros(shape_hw, np.uint8)
    for box in boxes:
        if classes is None or box.class_id in classes:
            cv2.rectangle(raster, (int(box.x0 * scale), int(box.y0 * scale)),
                          (int(np.ceil(box.x1 * scale)) - 1, int(np.ceil(box.y1 * scale)) - 1), 1, -1)
    return raster


def _water_seed(lab: np.ndarray, texture: np.ndarray, outside_boxes: np.ndarray,
                settings: BoxLabelSettings) -> tuple[np.ndarray, np.ndarray] | None:
    """Smooth regions that are water: the largest one, then those of its chroma (or in
    its shade) near it. Returns (seed mask, the water's mean a*b*) or None."""
    h, w = texture.shape
    smooth = ((texture < settings.smooth_texture) & (outside_boxes > 0)).astype(np.uint8)
    count, components, stats, _ = cv2.connectedComponentsWithStats(smooth, connectivity=8)
    if count < 2:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = np.argsort(-areas)
    main = int(order[0]) + 1
    main_pixels = lab[components == main]
    water_ab = main_pixels[:, 1:].mean(axis=0)
    water_lightness = float(main_pixels[:, 0].mean())
    seed = (components == main).astype(np.uint8)
    candidates = []
    for index in order[1:80]:
        if areas[index] < 0.001 * h * w:
            break
        pixels = lab[components == index + 1]
        ab = pixels[:, 1:].mean(axis=0)
        lightness = float(pixels[:, 0].mean())
        same_chroma = (np.linalg.norm(ab - water_ab) < settings.seed_chroma_distance
                       and lightness < water_lightness + 10)
        in_shade = (lightness < water_lightness - 25 and ab[1] < water_ab[1] - 5
                    and abs(ab[0] - 128) < 6)
        if same_chroma or in_shade:
            candidates.append(index + 1)
    near = _disk(10)
    for _ in range(4):  # grow through regions near the seed, a few steps at most
        grown = cv2.dilate(seed, near)
        joined = [c for c in candidates if grown[components == c].any()]
        if not joined:
            break
        for c in joined:
            seed[components == c] = 1
            candidates.remove(c)
    return seed, water_ab


def water_mask(image_bgr: np.ndarray, boxes: Sequence, settings: BoxLabelSettings,
               scale: float) -> np.ndarray | None:
    """Boolean water mask of ``image_bgr`` (already at the working size); ``boxes`` in
    pixels of the original image, ``scale`` maps them to the working size. None when the
    frame has no smooth region to seed the water from."""
    h, w = image_bgr.shape[:2]
    lab = cv2.cvtColor(cv2.GaussianBlur(image_bgr, (5, 5), 0), cv2.COLOR_BGR2LAB).astype(np.float32)
    texture = _texture(lab[..., 0])
    in_boxes = _box_raster((h, w), boxes, scale)
    outside = 1 - in_boxes
    seeded = _water_seed(lab, texture, outside, settings)
    if seeded is None:
        return None
    seed, water_ab = seeded
    a_blur = cv2.GaussianBlur(lab[..., 1], (0, 0), 6.0)
    b_blur = cv2.GaussianBlur(lab[..., 2], (0, 0), 6.0)
    features = np.dstack([np.clip(texture * 5, 0, 255), a_blur, b_blur]).astype(np.uint8)
    greener = a_blur < water_ab[0] - 4  # foliage and lawns; glint on water is not greener

    mask = np.full((h, w), cv2.GC_PR_BGD, np.uint8)
    mask[texture < settings.probable_water_texture] = cv2.GC_PR_FGD
    solid = ((texture > settings.solid_texture) & greener).astype(np.uint8)
    mask[cv2.erode(solid, _disk(3)) > 0] = cv2.GC_BGD
    # smooth, far brighter than the water, and boxed (canopies, decks, white hulls) or
    # not paler than it (bare soil, sand; glint is paler)
    water_lightness = float(lab[..., 0][seed > 0].mean())
    l_blur = cv2.GaussianBlur(lab[..., 0], (0, 0), 2.0)
    bright = (l_blur > water_lightness + 40) & (texture < settings.probable_water_texture)
    water_chroma = float(np.hypot(water_ab[0] - 128, water_ab[1] - 128))
    paler = np.hypot(a_blur - 128, b_blur - 128) < water_chroma - 3  # glint is whiter than water
    mask[bright & ((cv2.dilate(in_boxes, _disk(5)) > 0) | ~paler)] = cv2.GC_BGD
    mask[cv2.erode(seed, _disk(7)) > 0] = cv2.GC_FGD
    _grabcut(features, mask, settings.grabcut_iterations)
    water = np.isin(mask, (cv2.GC_FGD, cv2.GC_PR_FGD)).astype(np.uint8)

    # keep the water that is connected to the seed (a smooth lawn or roof is not a lake)
    # through necks at least 9 px wide: a path behind a dock is not reached
    opened = cv2.morphologyEx(water, cv2.MORPH_OPEN, _disk(4))
    count, components = cv2.connectedComponents(opened, connectivity=8)
    keep = np.zeros(count, bool)
    keep[np.unique(components[(seed > 0) & (opened > 0)])] = True
    keep[0] = False
    water = water & cv2.dilate(keep[components].astype(np.uint8), _disk(5))

    # sun glint: bright, sparkling, paler than the water, not green, large and surrounded by
    # water (but for the image edge) -> water
    l_blur = cv2.GaussianBlur(lab[..., 0], (0, 0), 6.0)
    glint = ((water == 0) & ~greener & paler & (l_blur > water_lightness + 8)
             & (texture > settings.probable_water_texture)).astype(np.uint8)
    count, components, stats, _ = cv2.connectedComponentsWithStats(glint, connectivity=8)
    beside_water = np.unique(components[cv2.dilate(water, _disk(3)) > 0])
    boxed_area = np.bincount(components[in_boxes > 0], minlength=count)
    for index in beside_water[beside_water > 0]:
        area = stats[index, cv2.CC_STAT_AREA]
        if area < 0.005 * h * w or boxed_area[index] >= 0.3 * area:  # docks are boxed
            continue
        region = (components == index).astype(np.uint8)
        ring = (cv2.dilate(region, _disk(3)) > 0) & (region == 0)
        ring[[0, -1], :] = False
        ring[:, [0, -1]] = False
        if ring.any() and water[ring].mean() > 0.7:  # glint lies in the water, rip-rap beside it
            water[(region > 0) & (in_boxes == 0)] = 1

    # the water line onto the colour edge, inside a narrow band
    band = _disk(6)
    mask = np.where(water > 0, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    mask[cv2.erode(water, band) > 0] = cv2.GC_FGD
    mask[cv2.erode(1 - water, band) > 0] = cv2.GC_BGD
    if (mask == cv2.GC_FGD).any() and (mask == cv2.GC_BGD).any():
        _grabcut(image_bgr, mask, 2)
        water = np.isin(mask, (cv2.GC_FGD, cv2.GC_PR_FGD)).astype(np.uint8)
    return water > 0


def _grabcut(image: np.ndarray, mask: np.ndarray, iterations: int) -> None:
    """GrabCut in place on ``mask`` (needs both a foreground and a background sample)."""
    has_fg = np.isin(mask, (cv2.GC_FGD, cv2.GC_PR_FGD)).any()
    has_bg = np.isin(mask, (cv2.GC_BGD, cv2.GC_PR_BGD)).any()
    if not (has_fg and has_bg):
        return
    background = np.zeros((1, 65), np.float64)
    foreground = np.zeros((1, 65), np.float64)
    cv2.grabCut(np.ascontiguousarray(image), mask, None, background, foreground, iterations,
                cv2.GC_INIT_WITH_MASK)


def _cut_vessel(image_bgr: np.ndarray, box, settings: BoxLabelSettings) -> tuple[tuple[int, int], np.ndarray]:
    """The vessel inside one box, in pixels of the full-resolution image (module docstring,
    step 2): ``((x0, y0), mask)`` of a crop around the box; the mask is empty when GrabCut
    finds nothing."""
    h, w = image_bgr.shape[:2]
    margin = 0.4 * max(box.x1 - box.x0, box.y1 - box.y0) + 8
    x0, y0 = int(max(box.x0 - margin, 0)), int(max(box.y0 - margin, 0))
    x1, y1 = int(min(np.ceil(box.x1 + margin), w)), int(min(np.ceil(box.y1 + margin), h))
    if x1 - x0 < 3 or y1 - y0 < 3:
        return (x0, y0), np.zeros((max(y1 - y0, 0), max(x1 - x0, 0)), bool)
    zoom = settings.vessel_upsample
    crop = cv2.resize(image_bgr[y0:y1, x0:x1], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC)
    inside = np.zeros(crop.shape[:2], bool)
    inside[int((box.y0 - y0) * zoom):int(np.ceil((box.y1 - y0) * zoom)),
           int((box.x0 - x0) * zoom):int(np.ceil((box.x1 - x0) * zoom))] = True
    lab = cv2.cvtColor(crop, cv2.COLOR_BGR2LAB).astype(np.float32)
    mask = np.full(crop.shape[:2], cv2.GC_BGD, np.uint8)
    mask[inside] = cv2.GC_PR_FGD
    if (~inside).any():
        water_l = float(np.median(lab[..., 0][~inside]))
        chroma = np.hypot(lab[..., 1] - 128, lab[..., 2] - 128)
        shadow = inside & (lab[..., 0] < water_l - settings.shadow_darker_l) & (
            chroma < settings.shadow_max_chroma)
        mask[shadow] = cv2.GC_PR_BGD
    _grabcut(crop, mask, settings.vessel_iterations)
    vessel = np.isin(mask, (cv2.GC_FGD, cv2.GC_PR_FGD)).astype(np.uint8)
    count, components, stats, _ = cv2.connectedComponentsWithStats(vessel, connectivity=8)
    if count < 2:
        return (x0, y0), np.zeros((y1 - y0, x1 - x0), bool)
    largest = (components == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    hull = cv2.convexHull(cv2.findNonZero(largest))
    filled = cv2.fillConvexPoly(np.zeros_like(largest), hull, 1)
    # the interpolated edge pixels GrabCut takes put the outline half a pixel out: one ring off
    filled = cv2.erode(filled, np.ones((3, 3), np.uint8)).astype(np.float32)
    back = cv2.resize(filled, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    return (x0, y0), back >= 0.5


def _vessel_at_work_scale(image_bgr: np.ndarray, box, shape_hw: tuple[int, int],
                          settings: BoxLabelSettings) -> np.ndarray:
    """:func:`_cut_vessel` as a mask of the working size ``shape_hw`` (area-resampled: a
    pixel is vessel when at least half of it is)."""
    (x0, y0), cut = _cut_vessel(image_bgr, box, settings)
    full = np.zeros(image_bgr.shape[:2], np.float32)
    full[y0:y0 + cut.shape[0], x0:x0 + cut.shape[1]] = cut
    if full.shape != shape_hw:
        full = cv2.resize(full, (shape_hw[1], shape_hw[0]), interpolation=cv2.INTER_AREA)
    return full >= 0.5


def _boundary_band(labels: np.ndarray, width_px: int) -> np.ndarray:
    """Pixels within ``width_px`` of a boundary between two different labels."""
    if width_px <= 0:
        return np.zeros(labels.shape, bool)
    kernel = np.ones((2 * width_px + 1, 2 * width_px + 1), np.uint8)
    return cv2.dilate(labels, kernel) != cv2.erode(labels, kernel)


def label_from_boxes(image_bgr: np.ndarray, boxes: Sequence,
                     settings: BoxLabelSettings | None = None) -> BoxLabelResult:
    """A proposed label mask for one image from its boxes (pixels of the image; each box
    has ``class_id`` 0/1/2/255 and ``x0, y0, x1, y1``). See the module docstring."""
    settings = settings or BoxLabelSettings()
    # GrabCut starts its colour models by k-means++ on OpenCV's global RNG: seeded here, the
    # same image and boxes give the same proposal whatever was labelled before
    cv2.setRNGSeed(0)
    h0, w0 = image_bgr.shape[:2]
    scale = min(1.0, settings.work_long_side_px / max(h0, w0))
    size = (max(1, round(w0 * scale)), max(1, round(h0 * scale)))
    work = cv2.resize(image_bgr, size, interpolation=cv2.INTER_AREA) if scale < 1 else image_bgr.copy()
    h, w = work.shape[:2]
    notes: list[str] = []

    water = water_mask(work, boxes, settings, scale)
    if water is None:
        notes.append("no smooth region to seed the water: the whole frame is taken as solid")
        water = np.zeros((h, w), bool)
    labels = np.where(water, WATER, OBSTACLE).astype(np.uint8)
    solid = (~water).astype(np.uint8)

    explained = np.zeros((h, w), bool)
    for box in sorted(boxes, key=lambda b: b.class_id == SHIP):  # vessels painted last
        region = _box_raster((h, w), [box], scale) > 0
        explained |= region
        if box.class_id == SHIP:
            vessel = _vessel_at_work_scale(image_bgr, box, (h, w), settings)
            labels[region & (solid > 0) & ~vessel & (labels != SHIP)] = IGNORE
            labels[vessel] = SHIP
        elif box.class_id == IGNORE:
            labels[region & (solid > 0)] = IGNORE

    # unexplained solid islands in the water: unlabelled boats, buoys, wakes
    count, components, stats, _ = cv2.connectedComponentsWithStats(solid, connectivity=8)
    touches_edge = np.zeros(count, bool)
    for edge in (components[0], components[-1], components[:, 0], components[:, -1]):
        touches_edge[np.unique(edge)] = True
    explained_ids = np.unique(components[explained & (solid > 0)])
    small = stats[:, cv2.CC_STAT_AREA] <= settings.island_max_fraction * h * w
    island = small & ~touches_edge
    island[0] = False
    explained_island = np.zeros(count, bool)
    moderate = stats[:, cv2.CC_STAT_AREA] <= 0.03 * h * w
    explained_island[explained_ids] = (moderate & ~touches_edge)[explained_ids]
    explained_island[0] = False
    island[explained_ids] = False
    if island.any():
        labels[island[components]] = IGNORE
        notes.append(f"{int(island.sum())} unexplained solid island(s) in the water set to ignore")
    # the unboxed part of a boxed island (a wake behind a boat): ignore
    labels[explained_island[components] & ~explained] = IGNORE

    labels[_boundary_band(labels, settings.ignore_band_px)] = IGNORE
    if scale < 1:
        labels = cv2.resize(labels, (w0, h0), interpolation=cv2.INTER_NEAREST_EXACT)
    return BoxLabelResult(labels=labels, water_fraction=float((labels == WATER).mean()), notes=notes)

"""Proposed label masks for nadir marina tiles without any annotation
(``harborsight dataset label-marina``).

Orthophotos of marinas (rows of moored boats at pontoons, about 0.3 m per pixel) are mostly
dark open water and bright hulls. At that scale the gaps of water between moored boats are
a few pixels wide, too narrow for the texture model of :mod:`.from_boxes`, so water is found
per pixel:

1. **Water colour.** The darkest large region (Otsu threshold on CIELAB lightness, eroded by
   7 px, largest component) gives the water's mean and spread per channel; a pixel is water
   when every channel lies within 3 (L*) or 3.5 (a*, b*) spreads of that mean, or when it is
   darker than the water with the water's hue within 5 spreads (boat shadows on the water).
   Holes in the solid smaller than 25 px (dark cockpits, covers) are filled.
2. **Pontoons.** A pontoon is long, straight and narrow: a solid run that survives an opening
   with a line of ``pontoon_length_px`` at some angle (3-degree steps) but not an opening
   across it with a line of 13 px. Such runs are ``obstacle`` when their connected region is
   at most ``pontoon_width_px`` wide on average; a wider region is a dense **row of boats**
   whose bows line up along a pontoon.
   **A pontoon inside such a row** is found by its uniformity along its length: with the
   row's direction from its minimum-area rectangle, the standard deviation of L* along a
   line of ``row_line_px`` (mean filter m = k * L, m2 = k * L², sigma = sqrt(m2 - m²)) is
   at most ``row_std_max`` where the deck runs on (the boats beside it alternate hull,
   shadow and water along that line), and every pixel of the line is solid; such pixels,
   in straight runs at least ``row_min_length_px`` long and at most ``pontoon_width_px``
   wide, are ``obstacle``. The rest of the row is ``ship`` (the moored boats), except solid
   pixels within ``deck_band_px`` of a pontoon found anywhere, which are undecided (255):
   the detectors find a deck's uniform core, and its true width, worn planks and the bows
   touching it cannot be told apart from the colour. Solid parts thinner than 4 px (bow
   tips, lines) are undecided too, unless found as a pontoon or a finger pier.

   2b. **Walkways and finger piers anywhere.** A walkway wider than the 13-px
   cross-opening, or one whose boats bridge it into a wide band, is neither of the above.
   At each angle (3-degree steps), solid pixels whose line of ``row_line_px`` at that
   angle is fully solid and uniform (as above) form runs; a run at least
   ``row_min_length_px`` long and at most ``deck_width_max_px`` wide is a walkway
   (``obstacle``). Boats are shorter than the run, and alternate hull, shadow and water
   along a row. A finger pier is a shorter uniform run (``finger_line_px``, at most
   ``finger_std_max``) in solid narrower than ``finger_across_solid_px`` across it (a
   finger between water, not the edge of a hull), carried on to its ends, at least
   ``finger_min_length_px`` long and at most ``finger_width_max_px`` wide, that touches a
   walkway found (within 4 px).
3. **The rest.** Solid pixels greener than the water are ``obstacle`` (lawns and trees on the
   shore); every other solid pixel is ``ship``. Specks under 6 px are 255, and so is a
   1-px band wherever two decided classes meet (a pixel next to 255 keeps its class, so a
   narrow pontoon keeps its core).

Known limits: shore with buildings, car parks or rip-rap is taken for ship; so is a deck that
is not uniform along its length (dark wooden planks striped by the boats' shadows), and a
finger pier that touches no walkway found. Review every tile and correct those with
:mod:`.box_dataset`'s corrections (a pontoon as a ``line`` with a ``width``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from harborsight.datasets.from_boxes import OBSTACLE, SHIP, WATER, BoxLabelResult
from harborsight.perception.classes import IGNORE


@dataclass(frozen=True)
class MarinaSettings:
    """Lengths in pixels of the tile as given (0.3 m per pixel for the UC Merced tiles)."""

    pontoon_length_px: int = 150
    pontoon_width_px: float = 9.0
    hole_fill_px: int = 25
    row_line_px: int = 41
    row_std_max: float = 16.0
    row_min_length_px: int = 80
    deck_band_px: int = 3
    deck_width_max_px: float = 18.0
    finger_line_px: int = 21
    finger_std_max: float = 12.0
    finger_min_length_px: int = 20
    finger_width_max_px: float = 9.0
    finger_across_solid_px: int = 11


def _line_kernel(length_px: int, angle_deg: float) -> np.ndarray:
    half = length_px // 2
    kernel = np.zeros((2 * half + 1, 2 * half + 1), np.uint8)
    dx = np.cos(np.radians(angle_deg)) * half
    dy = np.sin(np.radians(angle_deg)) * half
    cv2.line(kernel, (round(half - dx), round(half - dy)), (round(half + dx), round(half + dy)), 1, 1)
    return kernel


def _water(lab: np.ndarray) -> np.ndarray | None:
    lightness = np.clip(lab[..., 0], 0, 255).astype(np.uint8)
    threshold, _ = cv2.threshold(lightness, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    dark = cv2.erode((lightness < threshold).astype(np.uint8), np.ones((7, 7), np.uint8))
    count, components, stats, _ = cv2.connectedComponentsWithStats(dark, connectivity=4)
    if count < 2:
        return None
    core = components == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if core.sum() < 200:
        return None
    pixels = lab[core]
    mean, spread = pixels.mean(axis=0), pixels.std(axis=0) + 2.0
    z = np.abs((lab - mean) / spread)
    water = (z[..., 0] < 3.0) & (z[..., 1] < 3.5) & (z[..., 2] < 3.5)
    water |= (lab[..., 0] < mean[0]) & (z[..., 1] < 5) & (z[..., 2] < 5)
    return water


def _elongated_parts(mask: np.ndarray):
    """Each 8-connected part of ``mask``: (its pixels, length and mean width in pixels, the
    direction of its length in degrees), from its minimum-area rectangle through the pixel
    centres (length = long side + 1, width = area / length)."""
    count, components, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    for index in range(1, count):
        region = components == index
        points = np.column_stack(np.nonzero(region)[::-1]).astype(np.float32)
        (_, _), (side_a, side_b), angle_deg = cv2.minAreaRect(points)
        length = max(side_a, side_b) + 1.0
        along_deg = angle_deg if side_a >= side_b else angle_deg + 90.0
        yield region, length, stats[index, cv2.CC_STAT_AREA] / length, along_deg


def _pontoons(solid: np.ndarray, settings: MarinaSettings) -> tuple[np.ndarray, np.ndarray]:
    """(narrow pontoon runs, wide line-like regions: rows of boats along a pontoon) as uint8
    masks."""
    runs = np.zeros_like(solid)
    for angle in range(0, 180, 3):
        along = cv2.morphologyEx(solid, cv2.MORPH_OPEN, _line_kernel(settings.pontoon_length_px, angle))
        wide = cv2.morphologyEx(along, cv2.MORPH_OPEN, _line_kernel(13, angle + 90))
        runs |= along & (1 - wide)
    narrow, undecided = np.zeros_like(solid), np.zeros_like(solid)
    for region, _, width, _ in _elongated_parts(runs):
        (narrow if width <= settings.pontoon_width_px else undecided)[region] = 1
    return narrow, undecided


def _along_line(lightness: np.ndarray, solid: np.ndarray, line: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(standard deviation of L*, share of solid pixels) over the line ``line`` (a kernel of
    :func:`_line_kernel`) centred on every pixel: mean filter m = k * L, m2 = k * L²,
    sigma = sqrt(m2 - m²)."""
    kernel = line.astype(np.float32) / line.sum()
    mean = cv2.filter2D(lightness, -1, kernel, borderType=cv2.BORDER_REFLECT)
    mean_sq = cv2.filter2D(lightness * lightness, -1, kernel, borderType=cv2.BORDER_REFLECT)
    sigma = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
    solid_share = cv2.filter2D(solid.astype(np.float32), -1, kernel, borderType=cv2.BORDER_REFLECT)
    return sigma, solid_share


def _pontoons_in_rows(lightness: np.ndarray, solid: np.ndarray, rows: np.ndarray,
                      settings: MarinaSettings) -> np.ndarray:
    """Pontoon decks inside wide rows of boats (module docstring, step 2) as a uint8 mask."""
    found = np.zeros_like(solid)
    for region, _, _, along_deg in _elongated_parts(rows):
        sigma, solid_share = _along_line(lightness, solid, _line_kernel(settings.row_line_px, along_deg))
        deck = (region & (sigma <= settings.row_std_max) & (solid_share > 0.97)).astype(np.uint8)
        for part, length, width, _ in _elongated_parts(deck):
            if length >= settings.row_min_length_px and width <= settings.pontoon_width_px:
                found[part] = 1
    return found


def _uniform_runs(lightness: np.ndarray, solid: np.ndarray, line_px: int, std_max: float,
                  min_length_px: float, max_width_px: float,
                  across_solid_max_px: int | None = None) -> list[np.ndarray]:
    """Straight runs of uniform solid: at each angle (3-degree steps), the pixels whose line
    of ``line_px`` at that angle is solid and uniform in L* (:func:`_along_line`),
    grouped into parts that run along that angle (within 10 degrees), at least
    ``min_length_px`` long and at most ``max_width_px`` wide on average.

    With ``across_solid_max_px`` only solid narrower than that across the run counts (a
    finger pier between water, not the edge of a hull or a walkway it crosses), and each part
    found is carried on to its ends (the line test stops half a line short of them) before
    its length is measured."""
    runs = []
    for angle in range(0, 180, 3):
        line = _line_kernel(line_px, angle)
        sigma, solid_share = _along_line(lightness, solid, line)
        deck = (solid > 0) & (sigma <= std_max) & (solid_share > 0.97)
        narrow_across = None
        if across_solid_max_px is not None:
            wide = cv2.morphologyEx(solid, cv2.MORPH_OPEN, _line_kernel(across_solid_max_px, angle + 90))
            narrow_across = (solid > 0) & (wide == 0)
            deck &= narrow_across
        if deck.sum() < min_length_px:
            continue
        for part, length, width, along_deg in _elongated_parts(deck.astype(np.uint8)):
            if narrow_across is not None:
                extended = ((cv2.dilate(part.astype(np.uint8), line) > 0) & narrow_across).astype(np.uint8)
                part, length, width, along_deg = max(_elongated_parts(extended), key=lambda p: p[0].sum())
            off_axis = abs((along_deg - angle + 90.0) % 180.0 - 90.0)
            if length >= min_length_px and width <= max_width_px and off_axis <= 10.0:
                runs.append(part)
    return runs


def _walkways(lightness: np.ndarray, solid: np.ndarray, settings: MarinaSettings) -> np.ndarray:
    """Walkways anywhere in the solid (module docstring, step 2b) as a uint8 mask: uniform
    straight runs at least ``row_min_length_px`` long and up to ``deck_width_max_px`` wide
    (boats are shorter, and alternate hull, shadow and water along a row), then the finger
    piers that touch them: shorter uniform runs (``finger_line_px``, ``finger_min_length_px``)
    at most ``finger_width_max_px`` wide."""
    found = np.zeros_like(solid)
    for part in _uniform_runs(lightness, solid, settings.row_line_px, settings.row_std_max,
                              settings.row_min_length_px, settings.deck_width_max_px):
        found[part] = 1
    if not found.any():
        return found
    reach = cv2.dilate(found, np.ones((9, 9), np.uint8)) > 0   # the deck found, and its edge
    for part in _uniform_runs(lightness, solid, settings.finger_line_px, settings.finger_std_max,
                              settings.finger_min_length_px, settings.finger_width_max_px,
                              settings.finger_across_solid_px):
        if (part & reach).any():
            found[part] = 1
    return found


def label_marina_tile(image_bgr: np.ndarray, settings: MarinaSettings | None = None) -> BoxLabelResult:
    """A proposed mask of one marina tile (module docstring)."""
    settings = settings or MarinaSettings()
    lab = cv2.cvtColor(cv2.GaussianBlur(image_bgr, (3, 3), 0), cv2.COLOR_BGR2LAB).astype(np.float32)
    water = _water(lab)
    if water is None:
        return BoxLabelResult(np.full(image_bgr.shape[:2], IGNORE, np.uint8), 0.0,
                              ["no dark region to take the water's colour from: all undecided"])
    solid = (~water).astype(np.uint8)
    count, components, stats, _ = cv2.connectedComponentsWithStats(1 - solid, connectivity=4)
    hole = np.zeros(count, bool)
    hole[1:] = stats[1:, cv2.CC_STAT_AREA] < settings.hole_fill_px
    solid[hole[components]] = 1

    labels = np.where(solid > 0, SHIP, WATER).astype(np.uint8)
    lightness = np.ascontiguousarray(lab[..., 0])
    narrow, rows = _pontoons(solid, settings)
    in_rows = _pontoons_in_rows(lightness, solid, rows, settings)
    narrow |= in_rows | _walkways(lightness, solid, settings)
    band = 2 * settings.deck_band_px + 1
    near_deck = cv2.dilate(narrow, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (band, band)))
    labels[(near_deck > 0) & (solid > 0)] = IGNORE
    labels[narrow > 0] = OBSTACLE
    opened = cv2.morphologyEx(solid, cv2.MORPH_OPEN, np.ones((4, 4), np.uint8))
    labels[(solid > 0) & (opened == 0) & (narrow == 0)] = IGNORE
    water_a = float(lab[..., 1][water].mean())
    labels[(lab[..., 1] < water_a - 6) & (solid > 0)] = OBSTACLE
    count, components, stats, _ = cv2.connectedComponentsWithStats(solid, connectivity=4)
    speck = np.zeros(count, bool)
    speck[1:] = stats[1:, cv2.CC_STAT_AREA] < 6
    labels[speck[components]] = IGNORE
    kernel = np.ones((3, 3), np.uint8)
    decided = labels != IGNORE
    boundary = np.zeros_like(decided)
    for cls in (WATER, SHIP, OBSTACLE):
        boundary |= decided & (labels != cls) & (cv2.dilate((labels == cls).astype(np.uint8), kernel) > 0)
    labels[boundary] = IGNORE
    notes = ([f"{int(rows.sum())} px of rows of boats along pontoons, "
              f"{int(in_rows.sum())} px of pontoon found inside them"] if rows.any() else [])
    return BoxLabelResult(labels, float((labels == WATER).mean()), notes)

"""Copy-paste of vessels onto open water: more of a rare class in real training frames.

On the lake-shore photos vessels are 0.09 % of the training pixels, a few dozen small boats,
most of them at docks; the model reads a boat under way on open water as water. Pasting the
training set's own boats onto open water of other training frames (Ghiasi et al. 2021,
"Simple Copy-Paste is a Strong Data Augmentation Method for Instance Segmentation") shows the
network many more boats, in places the frames rarely have them.

* **The bank** (:class:`VesselBank`): every connected ship region (class 1, 8-connected) of a
  dataset's training frames, in the view the training sees (after ``fit_large``), with an area
  of at least ``min_area_px`` pixels and at most ``max_area_fraction`` of its frame, not
  touching the frame's border (a cut boat is half a shape). Each keeps its pixels, its mask
  and its frame's number.
* **A paste** (:func:`paste_vessels`): 1 to ``max_vessels`` regions from other frames, each
  turned by a multiple of 90 degrees and perhaps mirrored (exact: no resampling), placed where
  the region grown by one pixel lies on water only (class 0), so a pasted boat never covers a
  dock, another boat or an undecided pixel. The image takes the boat through a mask
  softened by a Gaussian of ``feather_px`` (its inside opaque, its rim at least half the
  boat); the labels take ship (1) under the mask and ignore (255) on the one-pixel ring
  around it, where the softened edge is neither boat nor water.

Scale is kept: a bank serves its own dataset only, whose frames share a ground sampling
distance (lake-shore photos with photos, tiles with tiles).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from harborsight.perception.classes import IGNORE, SHIP, WATER

_RING = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class PastedRegion:
    """One vessel of the bank: ``pixels`` (h x w x 3 uint8, BGR) and ``mask`` (h x w bool),
    cut from frame ``frame`` of its dataset."""

    pixels: np.ndarray
    mask: np.ndarray
    frame: int


class VesselBank:
    """The vessels that can be pasted into one dataset's frames (module docstring)."""

    def __init__(self, regions: list[PastedRegion]) -> None:
        self.regions = regions

    def __len__(self) -> int:
        return len(self.regions)

    @classmethod
    def from_frames(cls, frames, indices, min_area_px: int = 12,
                    max_area_fraction: float = 0.02) -> VesselBank:
        """Cut every usable ship region out of ``frames[i]`` for ``i`` in ``indices``
        (``frames[i] -> (image, labels)``)."""
        regions = []
        for index in indices:
            image, labels = frames[index]
            regions += cut_vessels(image, labels, int(index), min_area_px, max_area_fraction)
        return cls(regions)


def cut_vessels(image: np.ndarray, labels: np.ndarray, frame: int = 0, min_area_px: int = 12,
                max_area_fraction: float = 0.02) -> list[PastedRegion]:
    """The ship regions of one frame that a bank keeps (module docstring)."""
    height, width = labels.shape
    count, components, stats, _ = cv2.connectedComponentsWithStats(
        (labels == SHIP).astype(np.uint8), connectivity=8)
    regions = []
    for k in range(1, count):
        x, y, w, h, area = (int(v) for v in stats[k])
        if area < min_area_px or area > max_area_fraction * height * width:
            continue
        if x == 0 or y == 0 or x + w == width or y + h == height:
            continue
        mask = components[y:y + h, x:x + w] == k
        regions.append(PastedRegion(image[y:y + h, x:x + w].copy(), mask, frame))
    return regions


def paste_vessels(image: np.ndarray, labels: np.ndarray, bank: VesselBank,
                  rng: np.random.Generator, frame: int | None = None, max_vessels: int = 3,
                  attempts: int = 12, feather_px: float = 0.6
                  ) -> tuple[np.ndarray, np.ndarray, int]:
    """Paste 1 to ``max_vessels`` vessels of ``bank`` (none cut from ``frame``) onto open
    water of ``image``/``labels``. Returns new arrays and the number pasted (0 when the bank
    has nothing to give or no place of open water fits)."""
    if image.shape[:2] != labels.shape:
        raise ValueError(f"image {image.shape[:2]} and labels {labels.shape} differ in size")
    candidates = [r for r in bank.regions if r.frame != frame]
    if not candidates:
        return image, labels, 0
    image, labels = image.copy(), labels.copy()
    height, width = labels.shape
    pasted = 0
    for _ in range(int(rng.integers(1, max_vessels + 1))):
        region = candidates[int(rng.integers(len(candidates)))]
        turns, mirrored = int(rng.integers(4)), bool(rng.random() < 0.5)
        pixels, mask = np.rot90(region.pixels, turns), np.rot90(region.mask, turns)
        if mirrored:
            pixels, mask = pixels[:, ::-1], mask[:, ::-1]
        # the mask with a one-pixel ring, on a canvas one pixel larger on every side
        h, w = mask.shape
        grown = cv2.dilate(np.pad(mask, 1).astype(np.uint8), _RING).astype(bool)
        if h + 2 > height or w + 2 > width:
            continue
        for _ in range(attempts):
            y0 = int(rng.integers(0, height - (h + 2) + 1))
            x0 = int(rng.integers(0, width - (w + 2) + 1))
            window = labels[y0:y0 + h + 2, x0:x0 + w + 2]
            if np.all(window[grown] == WATER):
                break
        else:
            continue
        inside = np.pad(mask, 1).astype(np.uint8)
        alpha = cv2.GaussianBlur(inside.astype(np.float32), (0, 0), feather_px)
        alpha = np.where(inside > 0, np.maximum(alpha, 0.5), alpha * grown)
        alpha[cv2.erode(inside, _RING) > 0] = 1.0     # only the boat's rim is blended
        alpha = alpha[..., None]
        source = np.pad(np.ascontiguousarray(pixels), ((1, 1), (1, 1), (0, 0)), mode="edge")
        target = image[y0:y0 + h + 2, x0:x0 + w + 2].astype(np.float32)
        blended = alpha * source.astype(np.float32) + (1.0 - alpha) * target
        image[y0:y0 + h + 2, x0:x0 + w + 2] = np.clip(np.rint(blended), 0, 255).astype(np.uint8)
        window[grown] = IGNORE
        window[np.pad(mask, 1)] = SHIP
        pasted += 1
    return image, labels, pasted

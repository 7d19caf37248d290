"""Review sheets of a labelled dataset: each image beside its mask blended over it (and,
where the dataset keeps them, the proposal the mask was corrected from), so that every mask
can be checked by eye."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from harborsight.perception.segment_images import overlay_image
from harborsight.viz.overlay import BLACK, WHITE


def _caption(picture: np.ndarray, text: str) -> None:
    """White text with a black rim in the bottom-left corner (the legend is top-left)."""
    where = (6, picture.shape[0] - 8)
    cv2.putText(picture, text, where, cv2.FONT_HERSHEY_SIMPLEX, 0.55, BLACK, 3, cv2.LINE_AA)
    cv2.putText(picture, text, where, cv2.FONT_HERSHEY_SIMPLEX, 0.55, WHITE, 1, cv2.LINE_AA)


def review_row(image_bgr: np.ndarray, labels: np.ndarray, title: str,
               proposal: np.ndarray | None = None, tile_width: int = 512) -> np.ndarray:
    """``[image | mask over image]`` (with ``proposal``: ``[image | proposal | mask]``),
    each tile ``tile_width`` wide; ignore (255) shows white."""
    height = round(tile_width * image_bgr.shape[0] / image_bgr.shape[1])
    size = (tile_width, height)

    def blended(mask: np.ndarray) -> np.ndarray:
        small = cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
        picture = overlay_image(cv2.resize(image_bgr, size, interpolation=cv2.INTER_AREA), small)
        picture[small == 255] = (255, 255, 255)
        return picture

    left = cv2.resize(image_bgr, size, interpolation=cv2.INTER_AREA)
    _caption(left, title)
    tiles = [left]
    if proposal is not None:
        tiles.append(blended(proposal))
        _caption(tiles[-1], "proposal")
    tiles.append(blended(labels))
    _caption(tiles[-1], "reviewed" if proposal is not None else "mask")
    gap = np.full((height, 4, 3), 255, np.uint8)
    parts = []
    for tile in tiles:
        parts += [tile, gap]
    return np.hstack(parts[:-1])


def review_sheets(dataset_dir: str | Path, out_dir: str | Path, stems: list[str],
                  rows_per_sheet: int = 4, tile_width: int = 384, suffix: str = ".jpg",
                  jpeg_quality: int = 75) -> list[Path]:
    """Write ``out_dir/review_NN<suffix>`` sheets (JPEG at ``jpeg_quality``, small enough
    to keep beside a dataset) of ``rows_per_sheet`` frames each; returns their paths.
    Frames whose image or mask is missing are left out."""
    dataset_dir, out_dir = Path(dataset_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for stem in stems:
        images = sorted((dataset_dir / "images").glob(f"{stem}.*"))
        image = cv2.imread(str(images[0]), cv2.IMREAD_COLOR) if images else None
        labels = cv2.imread(str(dataset_dir / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        if image is None or labels is None:
            continue
        proposal_path = dataset_dir / "proposals" / f"{stem}.png"
        proposal = cv2.imread(str(proposal_path), cv2.IMREAD_UNCHANGED) if proposal_path.is_file() else None
        rows.append(review_row(image, labels, stem, proposal, tile_width))
    paths = []
    for k in range(0, len(rows), rows_per_sheet):
        chunk = rows[k:k + rows_per_sheet]
        width = max(r.shape[1] for r in chunk)
        chunk = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in chunk]
        path = out_dir / f"review_{k // rows_per_sheet:02d}{suffix}"
        if not cv2.imwrite(str(path), np.vstack(chunk), [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality]):
            raise OSError(f"{path}: could not be written")
        paths.append(path)
    return paths

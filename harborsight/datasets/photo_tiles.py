"""Label masks for tiles cut from labelled photos: each tile is registered to its photo and
the photo's reviewed mask is carried over, so that one review covers both scales.

Box datasets (Roboflow exports) often hold a flight twice: the photos, and tiles cut from the
full-resolution originals. A tile shows the scene at a finer scale (about 4 cm per pixel
against 8.5 cm for the 2048-px photos of the lake-shore set), the scale a model must also
handle.

**Registration.** SIFT features of the tile, shrunk to the photo's scale, are matched to the
photo's (Lowe's ratio test, 0.75) and a similarity ``photo = s R tile + t`` is fitted with
RANSAC (``cv2.estimateAffinePartial2D``, 2 px). A tile with at least ``min_inliers``
consistent matches is placed by its own fit. The fits of a photo's tiles, mapped back to the
tiles' stated positions in the original (``x0``, ``y0``), also give a photo model
``photo = s R native + t`` (the exporter zoomed some photos by up to 4 %): a tile with too
few features (open water, uniform lawn) is placed by that model when at least two tiles
agree with it to ``agree_px``. Every placement is checked by the normalised
cross-correlation of the tile and the photo warped onto it, over the pixels the photo covers.

**Labels.** The photo's mask is warped onto the tile as one channel per class (water, ship,
obstacle, ignore), bilinearly, and each tile pixel takes the class of largest weight: class
boundaries come out smooth rather than as the photo mask's up-scaled staircase, and the
mask's undecided band (255) widens with the scale. Tile pixels outside the photo (the
exporter cropped some photos) are 255.

Pixel coordinates are OpenCV's: pixel ``(i, j)`` is centred at ``x = i``; a resize by ``k``
maps ``x`` to ``k (x + 0.5) - 0.5``.
"""

from __future__ import annotations

import csv
import hashlib
from collections import Counter, defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from harborsight import __version__
from harborsight.datasets.layout import CLASSES, SCHEMA
from harborsight.errors import InputError
from harborsight.files import strict_json, write_bytes_atomic, write_text_atomic
from harborsight.perception.classes import IGNORE
from harborsight.training.dataset import read_split_map

#: the classes warped as channels, in channel order (IGNORE last)
_CHANNEL_CLASSES = (0, 1, 2, IGNORE)


@dataclass(frozen=True)
class TileSource:
    """One tile: its file, the photo it was cut from and its stated top-left corner in the
    photo's full-resolution original (``None`` when not known)."""

    tile_path: Path
    photo_stem: str
    x0_native: float | None = None
    y0_native: float | None = None


@dataclass(frozen=True)
class TilePlacement:
    """Where a tile lies in its photo: ``tile_to_photo`` (2x3) maps tile pixels (at the
    tile's full size) to pixels of the photo as registered, ``photo_size`` (width, height)."""

    source: TileSource
    tile_to_photo: np.ndarray
    method: str            # "features" or "photo model"
    inliers: int           # RANSAC inliers of the tile's own fit (0: none)
    ncc: float             # tile vs warped photo, over the pixels the photo covers
    photo_coverage: float  # share of the tile's pixels inside the photo
    photo_size: tuple[int, int]


@dataclass
class TileRegistrationSettings:
    min_inliers: int = 20        # matches a tile's own fit needs
    agree_px: float = 1.5        # photo-model residual (photo pixels) that counts as agreement
    min_ncc: float = 0.8         # below this a placement is refused
    ratio: float = 0.75          # Lowe's ratio test
    ransac_px: float = 2.0       # RANSAC threshold in photo pixels
    max_features: int = 4000


def _scale(kx: float, ky: float | None = None) -> np.ndarray:
    """3x3 map of a resize by ``kx`` (and ``ky`` down, default ``kx``) in OpenCV's
    pixel-centre convention."""
    ky = kx if ky is None else ky
    return np.array([[kx, 0, 0.5 * kx - 0.5], [0, ky, 0.5 * ky - 0.5], [0, 0, 1]], float)


def _h(affine: np.ndarray) -> np.ndarray:
    return np.vstack([np.asarray(affine, float), [0, 0, 1]])


def read_tile_positions(path: str | Path, tiles_dir: str | Path,
                        native_size: tuple[int, int] | None = None) -> list[TileSource]:
    """Tiles listed in a CSV with columns ``tile_file`` and ``frame_id`` (the photo's stem),
    and optionally the tile's top-left corner in the photo's original, ``x0``/``y0`` or
    ``x0_native_WxH``/``y0_native_WxH``. Rows with an empty ``frame_id`` are left out."""
    path, tiles_dir = Path(path), Path(tiles_dir)
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            columns = list(reader.fieldnames or [])
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputError(path, None, f"cannot read the tile positions: {exc}") from None
    for needed in ("tile_file", "frame_id"):
        if needed not in columns:
            raise InputError(path, needed, "column missing" if columns else "empty file: no header")
    if not rows:
        raise InputError(path, None, "no rows")
    x_col = next((c for c in columns if c == "x0" or c.startswith("x0_native")), None)
    y_col = next((c for c in columns if c == "y0" or c.startswith("y0_native")), None)
    sources = []
    for line, row in enumerate(rows, start=2):
        if not (row.get("frame_id") or "").strip():
            continue
        corner = []
        for col in (x_col, y_col):
            text = (row.get(col) or "").strip() if col else ""
            try:
                corner.append(float(text) if text else None)
            except ValueError:
                raise InputError(path, col, f"line {line}: {text!r} is not a number") from None
        sources.append(TileSource(tiles_dir / row["tile_file"].strip(), row["frame_id"].strip(),
                                  *corner))
    return sources


def _own_fit(tile_small, photo_features, sift, settings) -> tuple[np.ndarray | None, int]:
    """Similarity small-tile -> photo from SIFT matches, and its inlier count."""
    kp_t, des_t = sift.detectAndCompute(tile_small, None)
    kp_p, des_p = photo_features
    if des_t is None or des_p is None or len(kp_t) < 4 or len(kp_p) < 4:
        return None, 0
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(des_t, des_p, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < settings.ratio * p[1].distance]
    if len(good) < 4:
        return None, 0
    src = np.float32([kp_t[m.queryIdx].pt for m in good])
    dst = np.float32([kp_p[m.trainIdx].pt for m in good])
    affine, inliers = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC,
                                                  ransacReprojThreshold=settings.ransac_px)
    if affine is None:
        return None, 0
    return affine, int(inliers.sum())


def _check(tile_gray: np.ndarray, photo_gray: np.ndarray, tile_to_photo: np.ndarray
           ) -> tuple[float, float]:
    """NCC of the tile and the photo warped onto it, over the covered pixels; coverage."""
    size = (tile_gray.shape[1], tile_gray.shape[0])
    warped = cv2.warpAffine(photo_gray, tile_to_photo, size,
                            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0)
    inside = cv2.warpAffine(np.ones_like(photo_gray), tile_to_photo, size,
                            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0) > 0
    coverage = float(inside.mean())
    if inside.sum() < 100:
        return -1.0, coverage
    a = warped[inside].astype(np.float64)
    b = tile_gray[inside].astype(np.float64)
    a, b = a - a.mean(), b - b.mean()
    denominator = np.sqrt((a * a).sum() * (b * b).sum())
    return (float((a * b).sum() / denominator) if denominator > 0 else 0.0), coverage


def _apply(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ affine[:, :2].T + affine[:, 2]


def _photo_model(fits: list[tuple[np.ndarray, np.ndarray]], agree_px: float
                 ) -> tuple[np.ndarray | None, int]:
    """The similarity native -> photo that most tiles' own fits agree with. ``fits`` holds,
    per tile, its corners and centre in the original's pixels and its own native -> photo
    map; a tile agrees when the two maps put those points within ``agree_px`` of each
    other. Returns the model refitted on the agreeing tiles' points, and their number."""
    best, best_agree = None, []
    for _points, candidate in fits:
        agree = [(points, own) for points, own in fits
                 if np.abs(_apply(candidate, points) - _apply(own, points)).max() <= agree_px]
        if len(agree) > len(best_agree):
            best, best_agree = candidate, agree
    if len(best_agree) >= 2:
        src = np.vstack([points for points, _own in best_agree])
        dst = np.vstack([_apply(own, points) for points, own in best_agree])
        refit, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.LMEDS)
        best = refit if refit is not None else best
    return best, len(best_agree)


def place_tiles(sources: list[TileSource], photo_paths: dict[str, Path],
                original_width: float | None, settings: TileRegistrationSettings | None = None,
                on_tile: Callable[[TileSource, str | None], None] | None = None
                ) -> tuple[list[TilePlacement], list[tuple[str, str]]]:
    """Register every tile to its photo (see the module docstring). ``original_width`` is
    the width of the originals the tiles were cut from (4000 for the lake-shore set): each
    tile is shrunk by its photo's width over it before matching (``None``: tiles and photos
    share a scale). Returns the placements and ``(file, reason)`` of the tiles left out."""
    settings = settings or TileRegistrationSettings()
    sift = cv2.SIFT_create(nfeatures=settings.max_features)
    by_photo: dict[str, list[TileSource]] = defaultdict(list)
    for source in sources:
        by_photo[source.photo_stem].append(source)
    placements, skipped = [], []

    def skip(source: TileSource, reason: str) -> None:
        skipped.append((str(source.tile_path), reason))
        if on_tile is not None:
            on_tile(source, reason)

    for photo_stem, tiles in by_photo.items():
        photo_path = photo_paths.get(photo_stem)
        photo = cv2.imread(str(photo_path), cv2.IMREAD_GRAYSCALE) if photo_path else None
        if photo is None:
            for source in tiles:
                skip(source, f"photo {photo_stem!r} not found or unreadable")
            continue
        photo_features = sift.detectAndCompute(photo, None)
        photo_size = (photo.shape[1], photo.shape[0])
        tile_scale_to_photo = photo.shape[1] / original_width if original_width else 1.0
        own: dict[int, tuple[int, np.ndarray]] = {}     # tile: inliers, tile -> photo
        grays: dict[int, np.ndarray] = {}
        for k, source in enumerate(tiles):
            gray = cv2.imread(str(source.tile_path), cv2.IMREAD_GRAYSCALE)
            if gray is None:
                continue
            grays[k] = gray
            small_size = (max(1, round(gray.shape[1] * tile_scale_to_photo)),
                          max(1, round(gray.shape[0] * tile_scale_to_photo)))
            small = cv2.resize(gray, small_size, interpolation=cv2.INTER_AREA)
            fit, inliers = _own_fit(small, photo_features, sift, settings)
            if fit is not None:
                to_small = _scale(small_size[0] / gray.shape[1], small_size[1] / gray.shape[0])
                own[k] = (inliers, (_h(fit) @ to_small)[:2])
        located = []
        for k, (inliers, full) in own.items():
            if inliers >= settings.min_inliers and tiles[k].x0_native is not None:
                height, width = grays[k].shape
                points = np.array([[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1],
                                   [(width - 1) / 2, (height - 1) / 2]], float)
                points += [tiles[k].x0_native, tiles[k].y0_native]
                located.append((points, (_h(full) @ np.linalg.inv(_native_offset(tiles[k])))[:2]))
        model, agreeing = _photo_model(located, settings.agree_px) if located else (None, 0)
        for k, source in enumerate(tiles):
            if k not in grays:
                skip(source, "tile image missing or unreadable")
                continue
            fit_inliers = own.get(k, (0, None))[0]
            if fit_inliers >= settings.min_inliers:
                tile_to_photo, method = own[k][1], "features"
            elif model is not None and agreeing >= 2 and source.x0_native is not None:
                tile_to_photo = (_h(model) @ _native_offset(source))[:2]
                method = "photo model"
            else:
                skip(source, f"not registered: {fit_inliers} feature matches (need "
                     f"{settings.min_inliers}) and no photo model agreed by two tiles")
                continue
            ncc, coverage = _check(grays[k], photo, tile_to_photo)
            if ncc < settings.min_ncc:
                skip(source, f"registration refused: tile vs photo NCC {ncc:.2f} (need "
                     f"{settings.min_ncc}) by {method}")
                continue
            placements.append(TilePlacement(source, tile_to_photo, method, fit_inliers, ncc, coverage,
                                            photo_size))
            if on_tile is not None:
                on_tile(source, None)
    return placements, skipped


def _native_offset(source: TileSource) -> np.ndarray:
    """3x3 map tile pixel -> pixel of the photo's original (a shift by the stated corner)."""
    return np.array([[1, 0, source.x0_native], [0, 1, source.y0_native], [0, 0, 1]], float)


def warp_labels(photo_labels: np.ndarray, out_to_labels: np.ndarray, out_size: tuple[int, int]
                ) -> np.ndarray:
    """The photo's mask seen through ``out_to_labels`` (2x3, output pixel -> mask pixel) at
    ``out_size`` (width, height): per-class channels warped bilinearly, the class of largest
    weight kept; outside the mask, 255."""
    onehot = np.stack([(photo_labels == c).astype(np.float32) for c in _CHANNEL_CLASSES], axis=-1)
    warped = cv2.warpAffine(onehot, out_to_labels, out_size,
                            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 1))
    return np.asarray(_CHANNEL_CLASSES, np.uint8)[np.argmax(warped, axis=-1)]


def tile_label(placement: TilePlacement, photo_labels: np.ndarray, tile_size: tuple[int, int],
               out_size: tuple[int, int]) -> np.ndarray:
    """The mask of one placed tile at ``out_size`` (width, height); ``tile_size`` is the
    tile's (width, height) as registered."""
    photo_size = placement.photo_size
    to_tile = _scale(tile_size[0] / out_size[0], tile_size[1] / out_size[1])
    to_labels = _scale(photo_labels.shape[1] / photo_size[0], photo_labels.shape[0] / photo_size[1])
    out_to_labels = (to_labels @ _h(placement.tile_to_photo) @ to_tile)[:2]
    return warp_labels(photo_labels, out_to_labels, out_size)


def tile_stem(source: TileSource) -> str:
    """A short stem that keeps the photo's: ``<photo>_t<8 hex of the tile's file name>``."""
    digest = hashlib.sha1(source.tile_path.name.encode("utf-8")).hexdigest()[:8]
    return f"{source.photo_stem}_t{digest}"


@dataclass
class TileDatasetResult:
    splits: dict[str, str] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    records: dict[str, dict] = field(default_factory=dict)


def write_tile_dataset(placements: list[TilePlacement], photo_dataset: str | Path, out_dir: str | Path,
                       max_side: int | None = None, skipped_before: list[tuple[str, str]] | None = None,
                       jpeg_quality: int = 85,
                       on_tile: Callable[[str, str | None], None] | None = None) -> TileDatasetResult:
    """Write the placed tiles as a dataset (``images/`` JPEG at ``jpeg_quality``,
    ``labels/`` PNG: the photo dataset's reviewed masks carried over), each tile in its
    photo's split; ``dataset.json`` records every tile's source file, placement method,
    inliers, NCC and photo coverage. Each placement's ``photo_size`` gives the scale to the
    photo dataset's masks."""
    photo_dataset, out_dir = Path(photo_dataset), Path(out_dir)
    photo_splits = read_split_map(photo_dataset)
    result = TileDatasetResult(skipped=list(skipped_before or []))
    for sub in ("images", "labels"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    photo_cache: dict[str, np.ndarray | None] = {}
    try:
        for placement in placements:
            source = placement.source
            stem = tile_stem(source)
            problem = _write_tile(placement, stem, photo_dataset, photo_splits, photo_cache, out_dir,
                                  max_side, jpeg_quality)
            if problem is None:
                result.splits[stem] = photo_splits[source.photo_stem]
                result.records[stem] = {
                    "tile": source.tile_path.name, "photo": source.photo_stem,
                    "method": placement.method, "inliers": placement.inliers,
                    "ncc": round(placement.ncc, 4), "photo_coverage": round(placement.photo_coverage, 4),
                    "tile_to_photo": [[round(float(v), 6) for v in row] for row in placement.tile_to_photo]}
            else:
                result.skipped.append((str(source.tile_path), problem))
            if on_tile is not None:
                on_tile(stem, problem)
    finally:
        if result.splits:
            _write_tile_doc(out_dir, photo_dataset, result, max_side)
    return result


def _write_tile(placement: TilePlacement, stem: str, photo_dataset: Path,
                photo_splits: dict[str, str], photo_cache: dict, out_dir: Path,
                max_side: int | None, jpeg_quality: int) -> str | None:
    source = placement.source
    if source.photo_stem not in photo_splits:
        return f"photo {source.photo_stem!r} is not in {photo_dataset / 'dataset.json'}"
    if source.photo_stem not in photo_cache:
        labels = cv2.imread(str(photo_dataset / "labels" / f"{source.photo_stem}.png"),
                            cv2.IMREAD_UNCHANGED)
        photo_cache.clear()
        photo_cache[source.photo_stem] = None if labels is None or labels.ndim != 2 else labels
    labels = photo_cache[source.photo_stem]
    if labels is None:
        return f"the photo's mask labels/{source.photo_stem}.png is missing or unreadable"
    tile = cv2.imread(str(source.tile_path), cv2.IMREAD_COLOR)
    if tile is None:
        return "tile image missing or unreadable"
    tile_size = (tile.shape[1], tile.shape[0])
    out_size = tile_size
    if max_side is not None and max(tile_size) > max_side:
        k = max_side / max(tile_size)
        out_size = (max(1, round(tile_size[0] * k)), max(1, round(tile_size[1] * k)))
        tile = cv2.resize(tile, out_size, interpolation=cv2.INTER_AREA)
    mask = tile_label(placement, labels, tile_size, out_size)
    ok_image, jpeg = cv2.imencode(".jpg", tile, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    ok_mask, png = cv2.imencode(".png", mask)
    if not (ok_image and ok_mask):
        return "encoding failed"
    write_bytes_atomic(out_dir / "images" / f"{stem}.jpg", jpeg.tobytes())
    write_bytes_atomic(out_dir / "labels" / f"{stem}.png", png.tobytes())
    return None


def _write_tile_doc(out_dir: Path, photo_dataset: Path, result: TileDatasetResult,
                    max_side: int | None) -> None:
    methods = Counter(record["method"] for record in result.records.values())
    doc = {
        "schema": SCHEMA,
        "generator": f"harborsight dataset label-tiles {__version__}",
        "time": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "source": {"format": "tiles of labelled photos", "photo_dataset": str(photo_dataset.resolve())},
        "classes": CLASSES,
        "ignore_index": IGNORE,
        "split": dict(sorted(result.splits.items())),
        "frames_without_pose": True,
        "max_side": max_side,
        "labels": "the photo dataset's reviewed masks warped onto each registered tile "
                  "(harborsight.datasets.photo_tiles); 255 outside the photo",
        "placements": dict(sorted(methods.items())),
        "tiles": dict(sorted(result.records.items())),
        "skipped": [{"file": f, "reason": r} for f, r in result.skipped],
    }
    write_text_atomic(out_dir / "dataset.json", strict_json(doc, indent=1) + "\n")

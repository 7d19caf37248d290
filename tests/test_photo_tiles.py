"""Tiles cut from labelled photos (``harborsight dataset label-tiles``): registration and the
carried-over masks, checked against the geometry the test itself builds."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.datasets.photo_tiles import (
    TileSource,
    place_tiles,
    read_tile_positions,
    warp_labels,
)
from harborsight.errors import InputError

ORIGINAL_WH = (800, 600)     # the "full-resolution original" the tiles are cut from
TILE_WH = (200, 150)
PHOTO_ZOOM = 1.03            # the photo is the original zoomed about its centre (as the exporter did)
PHOTO_SCALE = 0.5            # and shrunk to half
CIRCLE = ((430.0, 260.0), 70.0)      # ship disc in the original's pixels (centre, radius)
BOX = (100.0, 380.0, 330.0, 520.0)  # obstacle rectangle x0, y0, x1, y1


def _original(seed: int = 0) -> np.ndarray:
    """A textured scene (blurred noise and blobs) with a smooth-only corner for SIFT to miss."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.uniform(0, 255, ORIGINAL_WH[::-1]).astype(np.float32), (0, 0), 2.0)
    image = cv2.normalize(noise, None, 30, 220, cv2.NORM_MINMAX)
    for _ in range(60):
        x, y = rng.uniform(0, ORIGINAL_WH[0]), rng.uniform(0, ORIGINAL_WH[1])
        cv2.circle(image, (int(x), int(y)), int(rng.uniform(4, 20)), float(rng.uniform(0, 255)), -1)
    ramp = np.tile(np.linspace(60, 180, 200, dtype=np.float32), (150, 1))
    image[450:600, 600:800] = ramp                         # smooth: no features
    return cv2.cvtColor(image.astype(np.uint8), cv2.COLOR_GRAY2BGR)


def _original_to_photo() -> np.ndarray:
    """2x3: original pixel -> photo pixel (zoom about the centre, then the shrink)."""
    cx, cy = (ORIGINAL_WH[0] - 1) / 2, (ORIGINAL_WH[1] - 1) / 2
    zoom = np.array([[PHOTO_ZOOM, 0, cx * (1 - PHOTO_ZOOM)], [0, PHOTO_ZOOM, cy * (1 - PHOTO_ZOOM)],
                     [0, 0, 1]])
    k = PHOTO_SCALE
    shrink = np.array([[k, 0, 0.5 * k - 0.5], [0, k, 0.5 * k - 0.5], [0, 0, 1]])
    return (shrink @ zoom)[:2]


def _truth_labels(points_xy: np.ndarray) -> np.ndarray:
    """Classes of points given in the original's pixels, from the shapes' definitions."""
    (cx, cy), radius = CIRCLE
    x0, y0, x1, y1 = BOX
    classes = np.zeros(len(points_xy), np.uint8)
    inside_box = ((points_xy[:, 0] >= x0) & (points_xy[:, 0] <= x1)
                  & (points_xy[:, 1] >= y0) & (points_xy[:, 1] <= y1))
    classes[inside_box] = 2
    classes[np.hypot(points_xy[:, 0] - cx, points_xy[:, 1] - cy) <= radius] = 1
    return classes


@pytest.fixture
def tile_set(tmp_path):
    """A photo dataset (one photo, its mask at half the photo's size), five tiles of its
    original and a positions CSV; tile ``t_bad`` claims a place it is not cut from."""
    original = _original()
    to_photo = _original_to_photo()
    photo_wh = (round(ORIGINAL_WH[0] * PHOTO_SCALE), round(ORIGINAL_WH[1] * PHOTO_SCALE))
    photo = cv2.warpAffine(original, to_photo, photo_wh, flags=cv2.INTER_AREA)
    dataset = tmp_path / "photos_ds"
    (dataset / "images").mkdir(parents=True)
    (dataset / "labels").mkdir()
    cv2.imwrite(str(dataset / "images" / "P1.png"), photo)
    # the photo's mask at half the photo's size, from the shapes mapped through the truth
    mask_wh = (photo_wh[0] // 2, photo_wh[1] // 2)
    ys, xs = np.mgrid[0:mask_wh[1], 0:mask_wh[0]]
    photo_px = np.stack([(xs.ravel() + 0.5) * 2 - 0.5, (ys.ravel() + 0.5) * 2 - 0.5], axis=1)
    inverse = cv2.invertAffineTransform(to_photo)
    original_px = photo_px @ inverse[:, :2].T + inverse[:, 2]
    cv2.imwrite(str(dataset / "labels" / "P1.png"), _truth_labels(original_px).reshape(mask_wh[::-1]))
    (dataset / "dataset.json").write_text(json.dumps({"split": {"P1": "val"}}))
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    corners = {"t_ship": (360, 180), "t_box": (120, 390), "t_mid": (200, 150),
               "t_smooth": (600, 450), "t_bad": (0, 0)}
    cut_from = dict(corners, t_bad=(600, 0))
    rows = ["tile_file,frame_id,x0_native_800x600,y0_native_800x600"]
    for name, (x0, y0) in corners.items():
        cx0, cy0 = cut_from[name]
        tile = original[cy0:cy0 + TILE_WH[1], cx0:cx0 + TILE_WH[0]]
        if name == "t_bad":  # featureless, so only the photo model can place it
            tile = cv2.GaussianBlur(tile, (0, 0), 25)
        cv2.imwrite(str(tiles / f"{name}.png"), tile)
        rows.append(f"{name}.png,P1,{x0},{y0}")
    rows.append("orphan.png,,,")                                    # no photo: left out
    (tmp_path / "positions.csv").write_text("\n".join(rows) + "\n")
    return tmp_path, dataset, tiles, corners


def test_tiles_are_placed_where_they_were_cut(tile_set):
    root, dataset, tiles, corners = tile_set
    sources = read_tile_positions(root / "positions.csv", tiles)
    assert [s.tile_path.name for s in sources] == [f"{n}.png" for n in corners]
    placements, skipped = place_tiles(sources, {"P1": dataset / "images" / "P1.png"},
                                      original_width=ORIGINAL_WH[0])
    placed = {p.source.tile_path.stem: p for p in placements}
    assert set(placed) == {"t_ship", "t_box", "t_mid", "t_smooth"}
    assert placed["t_smooth"].method == "photo model"
    assert placed["t_ship"].method == "features"
    # the featureless tile at a wrong stated place is refused by the correlation check
    assert next(r for f, r in skipped if f.endswith("t_bad.png")).startswith(
        "registration refused: tile vs photo NCC")
    to_photo = _original_to_photo()
    for name, placement in placed.items():
        x0, y0 = corners[name]
        grid = np.array([[0, 0], [199, 0], [199, 149], [0, 149], [100, 75]], float)
        truth = (grid + np.array([x0, y0])) @ to_photo[:, :2].T + to_photo[:, 2]
        found = grid @ placement.tile_to_photo[:, :2].T + placement.tile_to_photo[:, 2]
        # photo pixels: 0.02 measured; a half-pixel slip in a resize's map would be 0.26
        assert np.abs(found - truth).max() < 0.1, name
        assert placement.ncc > 0.9


def test_carried_over_masks_match_the_shapes(tile_set, tmp_path):
    root, dataset, _tiles, corners = tile_set
    out = tmp_path / "out"
    result = CliRunner().invoke(app, [
        "dataset", "label-tiles", str(root / "positions.csv"), "--photo-dataset", str(dataset),
        "--out", str(out), "--no-progress"])
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "dataset.json").read_text())
    assert sorted(doc["split"].values()) == ["val"] * 4            # each tile in its photo's split
    assert doc["placements"] == {"features": 3, "photo model": 1}
    assert any("t_bad.png" in s["file"] for s in doc["skipped"])
    assert (out / "review" / "review_00.jpg").is_file()
    for stem, record in doc["tiles"].items():
        x0, y0 = corners[record["tile"][:-4]]
        labels = cv2.imread(str(out / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        assert labels.shape == TILE_WH[::-1]
        ys, xs = np.mgrid[0:TILE_WH[1], 0:TILE_WH[0]]
        truth = _truth_labels(np.stack([xs.ravel() + x0, ys.ravel() + y0], 1)).reshape(labels.shape)
        decided = labels != 255
        # undecided: outside the photo (the zoom crops the original's rim) and mask edges
        assert record["photo_coverage"] - 0.05 < decided.mean() <= record["photo_coverage"] + 1e-9
        # the photo's mask is 4 original pixels a pixel: boundaries may move by about that
        assert (labels[decided] == truth[decided]).mean() > 0.97, record["tile"]
    ship_tile = next(s for s, r in doc["tiles"].items() if r["tile"] == "t_ship.png")
    ship_labels = cv2.imread(str(out / "labels" / f"{ship_tile}.png"), cv2.IMREAD_UNCHANGED)
    assert (ship_labels == 1).mean() > 0.4


def test_warped_labels_outside_the_photo_are_ignored():
    labels = np.zeros((10, 10), np.uint8)
    labels[:, 5:] = 2
    shift = np.array([[1.0, 0, 5], [0, 1, 0]])                    # output x -> mask x + 5
    out = warp_labels(labels, shift, (10, 10))
    assert (out[:, :4] == 2).all() and (out[:, 6:] == 255).all()


def test_bad_positions_are_named(tmp_path):
    csv_path = tmp_path / "p.csv"
    csv_path.write_text("tile,frame_id\na.png,P1\n")
    with pytest.raises(InputError, match="tile_file"):
        read_tile_positions(csv_path, tmp_path)
    csv_path.write_text("tile_file,frame_id,x0,y0\na.png,P1,12,zz\n")
    with pytest.raises(InputError, match="line 2"):
        read_tile_positions(csv_path, tmp_path)
    csv_path.write_text("")
    with pytest.raises(InputError, match="empty file"):
        read_tile_positions(csv_path, tmp_path)
    csv_path.write_text("tile_file,frame_id\n")
    with pytest.raises(InputError, match="no rows"):
        read_tile_positions(csv_path, tmp_path)


def test_a_missing_tile_or_photo_is_skipped_and_the_rest_placed(tile_set):
    root, dataset, tiles, _corners = tile_set
    sources = read_tile_positions(root / "positions.csv", tiles)
    sources.append(TileSource(tiles / "gone.png", "P1", 0, 0))
    sources.append(TileSource(tiles / "t_ship.png", "P2", 0, 0))
    placements, skipped = place_tiles(sources, {"P1": dataset / "images" / "P1.png"}, 800)
    reasons = dict(skipped)
    assert "missing or unreadable" in reasons[str(tiles / "gone.png")]
    assert any("photo 'P2' not found" in r for r in reasons.values())
    assert len(placements) == 4

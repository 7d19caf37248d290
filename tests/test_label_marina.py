"""label-marina: proposals for unannotated nadir marina tiles, on a synthetic marina."""

import json

import cv2
import numpy as np
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.datasets.marina import label_marina_tile

WATER_BGR = (70, 60, 30)  # dark teal, as in the UC Merced tiles


def noisy_water(rng: np.random.Generator) -> np.ndarray:
    """A 256x256 float32 BGR tile of dark water with pixel noise (sigma 3)."""
    return np.full((256, 256, 3), WATER_BGR, np.float32) + rng.normal(0, 3, (256, 256, 3))


def synthetic_marina(seed: int = 0):
    """A 256x256 tile: dark water with noise, one vertical pontoon (7 px wide, full height)
    with boats (14x34 px, white) moored on both sides 4 px off it, 6 px of water between
    boats, and a green lawn strip on the right. Returns (image, masks of pontoon, boats, lawn)."""
    rng = np.random.default_rng(seed)
    image = noisy_water(rng)
    pontoon = np.zeros((256, 256), bool)
    pontoon[:, 96:103] = True
    boats = np.zeros((256, 256), bool)
    for top in range(10, 240, 20):
        boats[top:top + 14, 58:92] = True      # west of the pontoon, 4 px of water to it
        boats[top:top + 14, 107:141] = True    # east
    lawn = np.zeros((256, 256), bool)
    lawn[:, 230:] = True
    image[pontoon] = (170, 180, 185)
    image[boats] = (235, 235, 235)
    image[boats & (rng.random((256, 256)) < 0.1)] = (150, 90, 40)  # dark covers, cockpits
    image[lawn] = (40, 150, 60)
    image[lawn] += rng.normal(0, 12, (int(lawn.sum()), 3))
    return np.clip(image, 0, 255).astype(np.uint8), pontoon, boats, lawn


def inner(mask, px=2):
    return cv2.erode(mask.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)) > 0


def test_water_boats_pontoon_and_lawn():
    image, pontoon, boats, lawn = synthetic_marina()
    labels = label_marina_tile(image).labels
    assert labels.shape == (256, 256) and labels.dtype == np.uint8
    water = ~(pontoon | boats | lawn)
    assert (labels[inner(water)] == 0).mean() > 0.99
    # the 6-px gaps between moored boats stay water (a texture model would close them)
    gap_rows = [top + 16 for top in range(10, 230, 20)]
    assert (labels[gap_rows, 68:83] == 0).mean() > 0.95
    assert (labels[inner(boats)] == 1).mean() > 0.95
    assert (labels[inner(lawn)] == 2).mean() > 0.95
    # the pontoon: a long, straight, narrow run -> obstacle where it is not hidden by a band
    core = np.zeros_like(pontoon)
    core[:, 98:101] = True
    assert (labels[core] == 2).mean() > 0.8
    assert not (labels[inner(boats)] == 2).any()
    # no two classes touch: a band of 255 between them
    for a, b in ((0, 1), (0, 2), (1, 2)):
        touching = cv2.dilate((labels == a).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert not (touching & (labels == b)).any()


def test_a_pontoon_bridged_to_the_boats_is_not_ship():
    """Deck planks bridge the pontoon to the boats on both sides: one solid band wider than
    the 13-px cross-opening, not a narrow run. Its deck is still found by its uniformity
    along its length (this was a known limitation until the walkway search)."""
    image = synthetic_marina()[0]
    image[:, 92:96] = image[:, 103:107] = (170, 180, 185)   # the gaps bridged by deck planks
    labels = label_marina_tile(image).labels
    assert not (labels[:, 98:101] == 1).any()


def walkway_marina(seed: int = 0):
    """A walkway 15 px wide (wider than the 13-px cross-opening) with boats moored against
    it on the west and, on the east, boats every 40 px with a finger pier (5 x 30 px) between
    each two of them. Returns (image, walkway, boats, fingers)."""
    rng = np.random.default_rng(seed)
    image = noisy_water(rng)
    walkway = np.zeros((256, 256), bool)
    walkway[:, 100:115] = True
    boats, fingers = np.zeros_like(walkway), np.zeros_like(walkway)
    for top in range(10, 240, 20):
        boats[top:top + 14, 66:100] = True      # west, bows against the walkway
    for top in range(6, 230, 40):
        boats[top:top + 14, 115:149] = True     # east
        fingers[top + 23:top + 28, 115:145] = True
    image[walkway | fingers] = (170, 180, 185)
    image[boats] = (235, 235, 235)
    image[boats & (rng.random((256, 256)) < 0.1)] = (150, 90, 40)
    return np.clip(image, 0, 255).astype(np.uint8), walkway, boats, fingers


def test_a_walkway_wider_than_a_pontoon_run_and_its_finger_piers_are_obstacle():
    """The moored boats are ship, the walkway's core and the finger piers' cores are
    obstacle; the pixels near a found deck are undecided, never ship."""
    image, walkway, boats, fingers = walkway_marina()
    labels = label_marina_tile(image).labels
    assert (labels[:, 104:111] == 2).mean() > 0.9
    assert not (labels[walkway] == 1).any()
    far_from_deck = boats.copy()
    far_from_deck[:, 94:121] = False
    assert (labels[inner(far_from_deck)] == 1).mean() > 0.95
    assert not (labels[boats] == 2).any()
    finger_cores = fingers & ~cv2.dilate(walkway.astype(np.uint8), np.ones((1, 9), np.uint8)).astype(bool)
    finger_cores &= inner(fingers, 1) | (fingers & np.roll(fingers, 1, 0) & np.roll(fingers, -1, 0))
    assert (labels[finger_cores] == 2).mean() > 0.8
    assert not (labels[fingers] == 1).any()


def test_a_tile_with_no_dark_region_is_all_undecided():
    image = np.full((64, 64, 3), 200, np.uint8)
    result = label_marina_tile(image)
    assert (result.labels == 255).all() and "no dark region" in result.notes[0]


def test_command_writes_a_reviewed_dataset(tmp_path):
    src = tmp_path / "tiles"
    src.mkdir()
    for k in range(3):
        cv2.imwrite(str(src / f"harbor{k:02d}.tif"), synthetic_marina(k)[0])
    (src / "harbor09.tif").write_bytes(b"II*\x00 broken")
    fixes = tmp_path / "fixes.yaml"
    fixes.write_text("harbor02: {exclude: shore taken for ship}\n"
                     "harbor01:\n  - class: ignore\n    box: [0, 0, 40, 40]\n")
    out = tmp_path / "ds"
    result = CliRunner().invoke(app, ["dataset", "label-marina", str(src), "--out", str(out),
                                      "--split", "val", "--corrections", str(fixes), "--no-progress"])
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "dataset.json").read_text())
    assert doc["split"] == {"harbor00": "val", "harbor01": "val"}
    assert sorted(s["file"].rsplit("/", 1)[-1] for s in doc["skipped"]) == ["harbor02.tif",
                                                                             "harbor09.tif"]
    labels = cv2.imread(str(out / "labels" / "harbor01.png"), cv2.IMREAD_UNCHANGED)
    proposal = cv2.imread(str(out / "proposals" / "harbor01.png"), cv2.IMREAD_UNCHANGED)
    assert (labels[:41, :41] == 255).all() and np.array_equal(labels[41:], proposal[41:])
    assert doc["proposal_agreement"]["per_image"]["harbor00"] == 1.0
    assert list((out / "review").glob("review_*.jpg"))


def test_a_pontoon_inside_a_row_of_bows_is_found_by_its_uniform_deck():
    """Bows lined up against both sides of the pontoon (2-px strips of alternating white hull
    and blue cover) make one straight band 11 px wide: too wide on average for a narrow run,
    so the whole band used to be left undecided. The deck is uniform along its length, the
    bows are not: the deck is obstacle, the bows are not."""
    image = synthetic_marina()[0]
    stripes = np.where((np.arange(256) // 8) % 2 == 0, 0, 1)
    for columns in (slice(94, 96), slice(103, 105)):
        image[:, columns] = np.array([(235, 235, 235), (150, 90, 40)], np.uint8)[stripes][:, None]
    labels = label_marina_tile(image).labels
    assert (labels[:, 98:101] == 2).mean() > 0.9
    assert not (labels[:, 94:96] == 2).any() and not (labels[:, 103:105] == 2).any()

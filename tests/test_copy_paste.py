"""Copy-paste of a dataset's own vessels onto open water (train --copy-paste DIR:P)."""

import json
import shlex
from pathlib import Path

import cv2
import numpy as np
import pytest

from harborsight.cli.training import parse_copy_paste
from harborsight.errors import InputError
from harborsight.perception.classes import IGNORE, OBSTACLE, SHIP, WATER
from harborsight.training.augment import AugmentConfig
from harborsight.training.config import TrainConfig
from harborsight.training.copy_paste import VesselBank, cut_vessels, paste_vessels
from harborsight.training.dataset import SegmentationFrames
from harborsight.training.samples import TrainingSamples


def boat_frame(size: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Water (grey 50) with a 4x9 boat (colour 200, 30, 30) at rows 20-23, cols 30-38, a
    boat cut by the left border, a 2-px speck, and an obstacle strip along the bottom."""
    image = np.full((size, size, 3), 50, np.uint8)
    labels = np.zeros((size, size), np.uint8)
    image[20:24, 30:39] = (200, 30, 30)
    labels[20:24, 30:39] = SHIP
    labels[40:44, 0:5] = SHIP                      # touches the border: half a boat
    labels[10, 10:12] = SHIP                        # too small
    labels[56:, :] = OBSTACLE
    return image, labels


def test_the_bank_keeps_whole_boats_only():
    image, labels = boat_frame()
    regions = cut_vessels(image, labels, frame=7, min_area_px=12)
    assert len(regions) == 1
    (boat,) = regions
    assert boat.mask.shape == (4, 9) and boat.mask.all() and boat.frame == 7
    assert (boat.pixels == (200, 30, 30)).all()
    # larger than max_area_fraction of the frame: left out
    assert cut_vessels(image, labels, max_area_fraction=30 / 64**2) == []


def test_a_paste_lands_on_open_water_with_an_ignore_ring():
    image, labels = boat_frame()
    bank = VesselBank(cut_vessels(image, labels, frame=0))
    target = np.full((64, 64, 3), 90, np.uint8)
    target_labels = np.full((64, 64), OBSTACLE, np.uint8)
    target_labels[8:40, 8:40] = WATER                 # the only open water
    out, out_labels, n = paste_vessels(target, target_labels, bank, np.random.default_rng(1),
                                       frame=5, max_vessels=3)
    assert n >= 1
    assert (out_labels == SHIP).sum() == 36 * n
    # nothing but water was covered: the obstacle is intact, and the changes stay inside it
    changed = out_labels != target_labels
    assert (target_labels[changed] == WATER).all()
    assert ((out_labels == OBSTACLE) == (target_labels == OBSTACLE)).all()
    # every boat pixel is ringed by ignore or another boat, never touching water
    grown = cv2.dilate((out_labels == SHIP).astype(np.uint8), np.ones((3, 3), np.uint8))
    assert set(np.unique(out_labels[(grown > 0) & (out_labels != SHIP)])) <= {IGNORE}
    # the image carries the boat's colour inside it (its rim is blended with the water), and is
    # unchanged away from the boats and their rings
    inner = cv2.erode((out_labels == SHIP).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert inner.sum() == 14 * n and (out[inner] == (200, 30, 30)).all()
    rim = (out_labels == SHIP) & ~inner
    assert (out[rim][:, 0] >= 90 + (200 - 90) // 2).all()
    assert (out[~(grown > 0) & ~changed] == 90).all()
    # the inputs are not modified
    assert (target == 90).all() and (target_labels[8:40, 8:40] == WATER).all()


def test_no_paste_without_room_or_from_the_same_frame():
    image, labels = boat_frame()
    bank = VesselBank(cut_vessels(image, labels, frame=3))
    solid = np.full((64, 64), OBSTACLE, np.uint8)
    _, same, n = paste_vessels(image, solid, bank, np.random.default_rng(0))
    assert n == 0 and (same == OBSTACLE).all()
    # the bank's only boat comes from frame 3: it is not pasted back into frame 3
    water = np.zeros((64, 64), np.uint8)
    _, _, n = paste_vessels(image, water, bank, np.random.default_rng(0), frame=3)
    assert n == 0


def make_boat_dataset(root: Path, frames: int = 3) -> Path:
    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    split = {}
    for k in range(frames):
        image, labels = boat_frame()
        cv2.imwrite(str(root / "images" / f"f{k}.png"), image)
        cv2.imwrite(str(root / "labels" / f"f{k}.png"), labels)
        split[f"f{k}"] = "train"
    (root / "dataset.json").write_text(json.dumps({"split": split}))
    return root


def test_samples_get_more_boats_and_are_otherwise_unchanged(tmp_path):
    data = make_boat_dataset(tmp_path / "lake")
    frames = SegmentationFrames([data], ["train"])
    config = AugmentConfig(crop_hw=(64, 64))
    plain = TrainingSamples(frames, seed=4, augmentation=config)
    off = TrainingSamples(frames, seed=4, augmentation=config, copy_paste=[0.0])
    on = TrainingSamples(frames, seed=4, augmentation=config, copy_paste=[1.0])
    more = 0
    for n in range(12):
        a, b, c = plain[n], off[n], on[n]
        assert all((x == y).all() for x, y in zip(a, b, strict=True))      # P = 0: the very same samples
        assert (c[1] == SHIP).sum() >= (a[1] == SHIP).sum()
        more += (c[1] == SHIP).sum() > (a[1] == SHIP).sum()
        again = on[n]                                            # a pure function of (seed, n)
        assert all((x == y).all() for x, y in zip(c, again, strict=True))
    assert more >= 10


def test_copy_paste_options_parse_and_are_checked(tmp_path):
    lake, sim = str(tmp_path / "lake"), str(tmp_path / "sim")
    assert parse_copy_paste([f"{lake}:0.7"], [sim, lake]) == [0.0, 0.7]
    with pytest.raises(InputError, match=r"copy_paste.*not one of the --data"):
        parse_copy_paste([f"{tmp_path / 'other'}:0.5"], [sim, lake])
    with pytest.raises(InputError, match=r"copy_paste.*DIR:P"):
        parse_copy_paste([f"{lake}:lots"], [sim, lake])
    with pytest.raises(InputError, match=r"copy_paste.*probabilities"):
        TrainConfig(model="ddrnet23_slim", data_dirs=[sim, lake], out_dir="x",
                    copy_paste=[0.0, 1.5])
    with pytest.raises(InputError, match=r"copy_paste.*2 dataset folder"):
        TrainConfig(model="ddrnet23_slim", data_dirs=[sim, lake], out_dir="x", copy_paste=[0.5])
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[sim, lake], out_dir="x",
                         copy_paste=[0.0, 0.7])
    words = shlex.split(config.command_line())
    assert words[words.index("--copy-paste") + 1] == f"{lake}:0.7"
    assert words.count("--copy-paste") == 1
    assert TrainConfig.from_dict(config.to_dict()).copy_paste == [0.0, 0.7]

"""The labelled real set in data/real/: readable as a training dataset, split by blocks of
neighbouring frames, and rebuilt exactly from ../shared/data/real plus the committed review."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from harborsight.datasets.box_dataset import read_corrections, write_box_dataset
from harborsight.datasets.classmap import parse_class_map, read_class_names
from harborsight.datasets.marina import label_marina_tile
from harborsight.datasets.yolo import read_yolo_boxes
from harborsight.training.dataset import list_frames, read_labelled_frame

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "data" / "real"
SHARED = ROOT.parent / "shared" / "data" / "real"
LAKE_MAP = ["boat=ship", "jetski=ship", "car=obstacle", "dock=obstacle", "lift=obstacle"]


@pytest.mark.parametrize("name, frames, size_wh", [("lakeshore", 42, (1024, 768)),
                                                   ("marina", 80, None)])
def test_the_real_sets_read_as_datasets(name, frames, size_wh):
    records = list_frames([REAL / name])
    assert len(records) == frames
    splits = {r.split for r in records}
    assert splits == {"train", "val"}
    for record in records:
        image, labels = read_labelled_frame(record)   # sizes and class values checked there
        if size_wh:
            assert image.shape[1::-1] == size_wh
        assert set(np.unique(labels)) <= {0, 1, 2, 255}
    # every frame has a reviewed label and the proposal it came from
    assert len(list((REAL / name / "proposals").glob("*.png"))) == frames


def number(stem: str) -> int:
    return int("".join(c for c in stem if c.isdigit()))


@pytest.mark.parametrize("name", ["lakeshore", "marina"])
def test_splits_are_blocks_of_neighbouring_frames(name):
    split = json.loads((REAL / name / "dataset.json").read_text())["split"]
    train = [number(s) for s, v in split.items() if v == "train"]
    val = [number(s) for s, v in split.items() if v == "val"]
    assert max(train) < min(val), "a val frame sits among the training frames"


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data/real is not beside the checkout")
def test_lakeshore_labels_rebuild_from_the_boxes_and_the_review(tmp_path):
    source = SHARED / "aerial-maritime-drone"
    images, _ = read_yolo_boxes(source / "boxes", source / "photos",
                                read_class_names(source / "classes.yaml"), parse_class_map(LAKE_MAP))
    # one photo with polygon corrections and a relabelled lift box, one accepted as proposed,
    # one with a jetski outlined by hand (the second review)
    stems = ("DJI_0298", "DJI_0284", "DJI_0268")
    chosen = [item for item in images if item.image_path.stem in stems]
    corrections = read_corrections(REAL / "lakeshore-corrections.yaml")
    assert corrections.box_classes["DJI_0298"] == {8: 1}
    assert corrections.box_classes["DJI_0268"] == {15: 255}
    write_box_dataset(chosen, tmp_path, dict.fromkeys(stems, "train"), corrections, max_side=1024)
    for stem in stems:
        rebuilt = cv2.imread(str(tmp_path / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        committed = cv2.imread(str(REAL / "lakeshore" / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(rebuilt, committed), stem


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data/real is not beside the checkout")
def test_marina_labels_rebuild_from_the_tiles():
    # two tiles of each kind (3.5 s a tile on the 2-core VM; the suite has a 10-minute budget)
    for stem in ("harbor10", "harbor71"):
        image = cv2.imread(str(SHARED / "ucmerced-harbor" / f"{stem}.tif"), cv2.IMREAD_COLOR)
        committed = cv2.imread(str(REAL / "marina" / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(label_marina_tile(image).labels, committed), stem
    # the review: no tile left out; the shores that the proposal took for ship are corrected
    assert not read_corrections(REAL / "marina-corrections.yaml").excluded
    for stem in ("harbor36", "harbor67"):
        image = cv2.imread(str(SHARED / "ucmerced-harbor" / f"{stem}.tif"), cv2.IMREAD_COLOR)
        proposal = label_marina_tile(image).labels
        committed = cv2.imread(str(REAL / "marina" / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        assert (committed == 2).mean() > (proposal == 2).mean() + 0.01, stem


def test_marina_rows_of_boats_are_decided():
    """Rows of moored boats are ship and their walkways obstacle, not left undecided: at most
    a fifth of any tile is 255, and most tiles show a pontoon."""
    masks = [cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
             for path in sorted((REAL / "marina" / "labels").glob("*.png"))]
    assert len(masks) == 80
    assert max((m == 255).mean() for m in masks) < 0.2
    assert np.mean([(m == 2).mean() > 0.01 for m in masks]) > 0.9
    assert np.mean([(m == 1).mean() for m in masks]) > 0.25


"""Dataset reader (splits, several folders, errors naming the file) and augmentation
(labels stay aligned with their pixels, reproducible per seed)."""

import json
import shutil

import cv2
import numpy as np
import pytest

from harborsight.errors import InputError
from harborsight.training.augment import (
    AugmentConfig,
    _rescale,
    augment,
    augment_weighted,
    haze,
    mirror,
)
from harborsight.training.dataset import SegmentationFrames, list_frames
from tests.conftest import TINY_SPLITS


@pytest.fixture
def dataset_copy(tiny_dataset, tmp_path):
    target = tmp_path / "copy"
    shutil.copytree(tiny_dataset, target)
    return target


def test_frames_by_split_over_several_folders(tiny_dataset, dataset_copy):
    train = SegmentationFrames([tiny_dataset], ["train"])
    assert len(train) == TINY_SPLITS.count("train")
    assert {r.split for r in train.records} == {"train"}
    image, labels = train[0]
    assert image.dtype == np.uint8 and image.shape == (72, 128, 3)
    assert labels.dtype == np.uint8 and labels.shape == (72, 128)
    assert set(np.unique(labels)) <= {0, 1, 2, 255}
    expected = cv2.imread(str(tiny_dataset / "images" / f"{train.records[0].stem}.png"))
    assert np.array_equal(image, expected)  # BGR, as OpenCV reads it
    both = SegmentationFrames([tiny_dataset, dataset_copy], ["val", "test"])
    assert len(both) == 2 * (TINY_SPLITS.count("val") + TINY_SPLITS.count("test"))
    assert {r.dataset_dir for r in both.records} == {tiny_dataset, dataset_copy}
    assert len(SegmentationFrames([tiny_dataset])) == len(TINY_SPLITS)
    assert both.common_size_hw() == (72, 128)


def _edit_split(root, edit):
    meta = json.loads((root / "dataset.json").read_text())
    edit(meta)
    (root / "dataset.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("breakage, expected", [
    (lambda d: (d / "labels" / "000000.png").unlink(), r"labels/000000.png: mask: mask file not found"),
    (lambda d: cv2.imwrite(str(d / "labels" / "000000.png"), np.zeros((10, 12), np.uint8)),
     r"labels/000000.png: mask: size 12x10 differs from the image's 128x72"),
    (lambda d: cv2.imwrite(str(d / "labels" / "000000.png"), np.full((72, 128), 5, np.uint8)),
     r"labels/000000.png: mask: unknown class values \[5\]"),
    (lambda d: _edit_split(d, lambda m: m["split"].pop("000001")),
     r"images/000001.png: no split entry for '000001'"),
    (lambda d: _edit_split(d, lambda m: m.pop("split")), r"dataset.json: split: missing"),
    (lambda d: (d / "images" / "000000.png").unlink(),
     r"images/000000.png: image file not found \(frame '000000' is listed"),
])
def test_errors_name_the_file(dataset_copy, breakage, expected):
    breakage(dataset_copy)
    with pytest.raises(InputError, match=expected):
        frames = SegmentationFrames([dataset_copy], ["train"])
        for i in range(len(frames)):
            frames[i]


def test_empty_split_lists_what_exists(tiny_dataset):
    with pytest.raises(InputError, match=r"no frames in split\(s\) \['holdout'\].*test \(2\), "
                                         r"train \(4\), val \(2\)"):
        list_frames([tiny_dataset], ["holdout"])


# ----------------------------------------------------------------------------- augmentation

#: a colour per class id, so an image can be checked against its labels pixel by pixel
LUT = {0: (200, 0, 0), 1: (0, 200, 0), 2: (0, 0, 200), 255: (0, 0, 0)}
NO_PHOTOMETRY = {"p_colour": 0.0, "p_blur": 0.0, "p_noise": 0.0, "p_jpeg": 0.0}


def coded_pair(h: int = 40, w: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """Asymmetric labels (ship strip on the left, obstacle block top right) and an image
    whose colour is a function of the label."""
    labels = np.zeros((h, w), np.uint8)
    labels[:, : w // 4] = 1
    labels[: h // 3, 2 * w // 3:] = 2
    image = np.zeros((h, w, 3), np.uint8)
    for value, colour in LUT.items():
        image[labels == value] = colour
    return image, labels


def test_mirror_and_flip_move_labels_with_pixels():
    image, labels = coded_pair()
    rng = np.random.default_rng(0)
    only_mirror = AugmentConfig(crop_hw=None, p_mirror=1.0, p_flip=0.0, p_scale=0.0, **NO_PHOTOMETRY)
    out_image, out_labels = augment(image, labels, rng, only_mirror)
    assert np.array_equal(out_labels, labels[:, ::-1])
    assert (out_labels[:, -1] == 1).all() and (out_labels[0, 0] == 2)  # ship strip now right
    assert np.array_equal(out_image, image[:, ::-1])
    only_flip = AugmentConfig(crop_hw=None, p_mirror=0.0, p_flip=1.0, p_scale=0.0, **NO_PHOTOMETRY)
    out_image, out_labels = augment(image, labels, rng, only_flip)
    assert np.array_equal(out_labels, labels[::-1]) and np.array_equal(out_image, image[::-1])
    assert np.array_equal(mirror(*mirror(image, labels))[1], labels)


@pytest.mark.parametrize("seed", range(6))
def test_geometric_augmentation_keeps_alignment(seed):
    image, labels = coded_pair()
    rng = np.random.default_rng(seed)
    # no scaling: every pixel must still carry its label's colour (padding: 255 and black)
    exact = AugmentConfig(crop_hw=(48, 48), p_scale=0.0, **NO_PHOTOMETRY)
    out_image, out_labels = augment(image, labels, rng, exact)
    assert out_labels.shape == (48, 48) and out_image.shape == (48, 48, 3)
    assert (out_labels == 255).any()  # 40 rows padded to 48
    for value, colour in LUT.items():
        assert (out_image[out_labels == value] == colour).all()
    # with scaling, the image is interpolated: all but edge pixels still match
    scaled = AugmentConfig(crop_hw=(32, 32), p_scale=1.0, scale_min=0.6, scale_max=1.8,
                           **NO_PHOTOMETRY)
    out_image, out_labels = augment(image, labels, rng, scaled)
    assert set(np.unique(out_labels)) <= {0, 1, 2, 255}  # nearest-neighbour: no new values
    expected = np.array([LUT[v] for v in out_labels.ravel()]).reshape(out_image.shape)
    match = (np.abs(out_image.astype(int) - expected).max(axis=2) <= 8).mean()
    assert match > 0.85


def test_rescaled_label_edge_stays_on_the_image_edge():
    """A vertical edge between columns 49 and 50, scaled by 1.365, lies at x = 68.25 (pixel
    corners): output pixel 68 (centre 68.5) is past it, and the bilinear image is above half
    there. cv2.INTER_NEAREST samples source column floor(68 / 1.365) = 49 and put the label
    edge half a pixel right of the image's."""
    image = np.zeros((4, 100, 3), np.uint8)
    image[:, 50:] = 255
    labels = (image[..., 0] > 0).astype(np.uint8)
    out_image, (out_labels,) = _rescale(image, [labels], 1.365)
    image_edge = int(np.argmax(out_image[0, :, 0] > 127))
    label_edge = int(np.argmax(out_labels[0] == 1))
    assert image_edge == label_edge == 68


def test_photometric_augmentation_leaves_labels_alone():
    image = np.random.default_rng(1).integers(30, 220, (40, 60, 3), dtype=np.uint8)
    labels = coded_pair()[1]
    every = AugmentConfig(crop_hw=None, p_mirror=0.0, p_flip=0.0, p_scale=0.0, p_colour=1.0,
                          p_blur=1.0, p_noise=1.0, p_jpeg=1.0)
    out_image, out_labels = augment(image, labels, np.random.default_rng(2), every)
    assert np.array_equal(out_labels, labels)
    assert out_image.dtype == np.uint8 and out_image.shape == image.shape
    assert np.abs(out_image.astype(int) - image).mean() > 2.0


def test_augmentation_is_reproducible_per_seed():
    image, labels = coded_pair()
    config = AugmentConfig(crop_hw=(32, 48), p_blur=0.5, p_noise=0.5, p_jpeg=0.5)

    def run(seed):
        return augment(image, labels, np.random.default_rng(seed), config)

    first, again, other = run(7), run(7), [run(s) for s in range(8, 12)]
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    assert any(not np.array_equal(first[0], o[0]) for o in other)


def test_haze_is_the_scattering_model_by_hand():
    """I·t + A·(1 - t): t = 0.5 and airlight (200, 180, 160) take a pixel (0, 100, 255) to
    (100, 140, 207.5 -> 208), a black frame to half the airlight; t = 1 leaves the frame."""
    image = np.zeros((2, 2, 3), np.uint8)
    image[0, 0] = (0, 100, 255)
    hazy = haze(image, 0.5, (200.0, 180.0, 160.0))
    assert hazy[0, 0].tolist() == [100, 140, 208] and hazy[1, 1].tolist() == [100, 90, 80]
    assert np.array_equal(haze(image, 1.0, (200.0, 180.0, 160.0)), image)


def test_haze_at_probability_zero_leaves_every_other_draw_as_it_was():
    """p_haze 0 draws nothing, so runs seeded before haze existed augment alike; p_haze 1
    lifts the blacks and dims the whites of every sample (transmission at most 0.95)."""
    image, labels = coded_pair()
    plain = AugmentConfig(crop_hw=(32, 48), p_blur=0.5, p_noise=0.5, p_jpeg=0.5)
    rng = np.random.default_rng(5)
    augment(image, labels, rng, plain)
    after_plain = rng.random()
    rng = np.random.default_rng(5)
    augment(image, labels, rng, AugmentConfig(crop_hw=(32, 48), p_blur=0.5, p_noise=0.5,
                                              p_jpeg=0.5, p_haze=0.0))
    assert rng.random() == after_plain
    black_white = np.zeros((32, 48, 3), np.uint8)
    black_white[:, 24:] = 255
    only_haze = AugmentConfig(crop_hw=None, p_mirror=0.0, p_flip=0.0, p_scale=0.0, p_colour=0.0,
                              p_blur=0.0, p_noise=0.0, p_jpeg=0.0, p_haze=1.0)
    for seed in range(5):
        hazy, same_labels = augment(black_white, np.zeros((32, 48), np.uint8),
                                    np.random.default_rng(seed), only_haze)
        assert hazy[:, :24].min() >= round(0.05 * (140 - 15)) and hazy[:, 24:].max() < 255
        assert not same_labels.any()


@pytest.mark.parametrize("seed", range(4))
def test_the_clean_view_is_the_same_crop_without_its_photometric_changes(seed):
    """The clean view (what a distillation teacher may see) has every geometric step of the
    sample: on the colour-coded pair, with the photometry forced on, each of its pixels
    carries its label's colour, while the augmented image is hazed and jittered. The sample
    itself is exactly the one drawn without asking for the clean view."""
    image, labels = coded_pair()
    config = AugmentConfig(crop_hw=(48, 48), p_mirror=0.5, p_flip=0.5, p_scale=0.0,
                           p_colour=1.0, p_blur=1.0, p_noise=1.0, p_jpeg=1.0, p_haze=1.0)
    plain = augment(image, labels, np.random.default_rng(seed), config)
    out_image, out_labels, clean = augment(image, labels, np.random.default_rng(seed), config,
                                           clean_view=True)
    assert np.array_equal(out_image, plain[0]) and np.array_equal(out_labels, plain[1])
    assert clean.shape == out_image.shape and clean.flags["C_CONTIGUOUS"]
    for value, colour in LUT.items():
        assert (clean[out_labels == value] == colour).all()
    assert np.abs(out_image.astype(int) - clean).mean() > 5
    weights = np.ones(labels.shape, np.float32)
    *weighted, weighted_clean = augment_weighted(image, labels, weights,
                                                 np.random.default_rng(seed), config,
                                                 clean_view=True)
    assert np.array_equal(weighted[0], out_image) and np.array_equal(weighted_clean, clean)


def test_small_objects_get_the_larger_weight():
    from harborsight.training.dataset import small_object_weights

    instances = np.zeros((50, 100), np.uint16)
    instances[0:4, 0:4] = 7            # 16 px: sqrt(1000 / 16) = 7.9, clipped to 5
    instances[10:20, 0:25] = 8         # 250 px: sqrt(4) = 2
    instances[20:50, 50:100] = 1       # 1500 px: large, weight 1
    labels = np.where(instances > 0, 2, 0).astype(np.uint8)
    labels[49, 0] = 255                # ignored water
    weights = small_object_weights(instances, labels, area_ref_px=1000.0, max_weight=5.0)
    assert weights.dtype == np.float32 and weights.shape == labels.shape
    assert (weights[0:4, 0:4] == 5.0).all() and weights[10:20, 0:25] == pytest.approx(2.0)
    assert (weights[20:50, 50:100] == 1.0).all() and weights[45, 10] == 1.0 == weights[49, 0]


@pytest.mark.parametrize("seed", range(4))
def test_weights_follow_the_labels_through_augmentation(seed):
    image, labels = coded_pair()
    weights = np.where(labels == 255, 1.0, labels + 1.0).astype(np.float32)   # a function of the label
    config = AugmentConfig(crop_hw=(48, 48), p_scale=1.0, scale_min=0.6, scale_max=1.8)
    plain = augment(image, labels, np.random.default_rng(seed), config)
    out_image, out_labels, out_weights = augment_weighted(image, labels, weights,
                                                          np.random.default_rng(seed), config)
    # the same sample as without weights, and the weights moved with the labels
    assert np.array_equal(out_image, plain[0]) and np.array_equal(out_labels, plain[1])
    valid = out_labels != 255
    assert np.array_equal(out_weights[valid], out_labels[valid] + 1.0)
    assert set(np.unique(out_weights[~valid])) <= {0.0, 1.0}   # padding 0, ignored pixels 1
    with pytest.raises(ValueError, match="weights"):
        augment_weighted(image, labels, weights[:5], np.random.default_rng(seed), config)


def test_a_frame_still_being_written_is_left_out(dataset_copy):
    """The simulator writes images first and the frame JSON last: an image without its frame
    JSON and split entry belongs to a frame in progress, not to the dataset yet."""
    shutil.copy(dataset_copy / "images" / "000000.png", dataset_copy / "images" / "000099.png")
    assert len(SegmentationFrames([dataset_copy])) == len(TINY_SPLITS)
    (dataset_copy / "frames" / "000099.json").write_text("{}")       # finished, but not listed
    with pytest.raises(InputError, match="no split entry for '000099'"):
        SegmentationFrames([dataset_copy])

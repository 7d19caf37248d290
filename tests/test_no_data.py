"""Pixels without a picture (alpha 0: an orthophoto's area outside its footprint, a rectified
frame's corners) are not seen water. They were read as the colour stored under them (black,
white, anything) and a segmenter or a mask made them water: clearance never seen."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.images import read_image, read_image_and_no_data
from harborsight.perception.confidence import SolidConfidence

SAMPLES = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples"
runner = CliRunner()


def picture(height: int = 60, width: int = 80) -> np.ndarray:
    rng = np.random.default_rng(1)
    return rng.integers(30, 220, (height, width, 3), dtype=np.uint8)


def corner(height: int, width: int) -> np.ndarray:
    """bool (H, W): a triangle in the top-left corner, as an orthophoto's edge."""
    blank = np.zeros((height, width), np.uint8)
    cv2.fillPoly(blank, [np.array([[0, 0], [width // 2, 0], [0, height // 2]], np.int32)], 1)
    return blank.astype(bool)


def bgra(image: np.ndarray, no_data: np.ndarray, stored=(255, 255, 255)) -> np.ndarray:
    out = np.dstack([image, np.full(image.shape[:2], 255, np.uint8)])
    out[no_data, :3] = stored
    out[no_data, 3] = 0
    return out


@pytest.mark.parametrize("suffix", [".png", ".tif", ".webp"])
def test_transparent_pixels_are_found_and_read_black(tmp_path, suffix):
    image, no_data = picture(), corner(60, 80)
    path = tmp_path / f"ortho{suffix}"
    assert cv2.imwrite(str(path), bgra(image, no_data),
                       [cv2.IMWRITE_WEBP_QUALITY, 101] if suffix == ".webp" else [])
    read, found = read_image_and_no_data(path)
    assert np.array_equal(found, no_data)
    assert (read[no_data] == 0).all()
    assert np.array_equal(read[~no_data], image[~no_data])
    if suffix != ".webp":       # lossless WebP drops the colour under alpha 0
        assert (read_image(path)[no_data] == 255).all()     # the plain reader: as stored


def test_opaque_images_and_palette_transparency(tmp_path):
    image = picture()
    for name in ("rgb.png", "rgb.jpg", "opaque.png"):
        data = bgra(image, np.zeros((60, 80), bool)) if name == "opaque.png" else image
        cv2.imwrite(str(tmp_path / name), data)
        read, found = read_image_and_no_data(tmp_path / name)
        assert found is None and read.shape == (60, 80, 3)
    palette = Image.new("P", (80, 60), 1)
    palette.putpalette([0, 0, 0, 40, 90, 200])
    palette.paste(0, (0, 0, 20, 10))                    # index 0, transparent by tRNS
    palette.save(tmp_path / "palette.png", transparency=0)
    _, found = read_image_and_no_data(tmp_path / "palette.png")
    assert found.sum() == 200 and found[:10, :20].all()


def test_segment_labels_no_data_255_and_says_how_much(tmp_path):
    image, no_data = picture(144, 256), corner(144, 256)
    cv2.imwrite(str(tmp_path / "ortho.png"), bgra(image, no_data))
    cv2.imwrite(str(tmp_path / "same_black.png"), bgra(image, no_data, (0, 0, 0))[..., :3])
    out = tmp_path / "masks"
    result = runner.invoke(app, ["segment", str(tmp_path / "ortho.png"),
                                 str(tmp_path / "same_black.png"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    labels = cv2.imread(str(out / "ortho.png"), cv2.IMREAD_UNCHANGED)
    opaque = cv2.imread(str(out / "same_black.png"), cv2.IMREAD_UNCHANGED)
    assert (labels[no_data] == 255).all()
    assert np.array_equal(labels[~no_data], opaque[~no_data])   # filled black before the model
    summary = {Path(i["input"]).name: i for i in json.loads((out / "segment.json").read_text())["images"]}
    assert summary["ortho.png"]["no_data_fraction"] == pytest.approx(no_data.mean(), abs=1e-6)
    assert summary["same_black.png"]["no_data_fraction"] == 0.0


def test_the_model_is_sure_a_pixel_without_a_picture_is_solid():
    logits = np.zeros((3, 4, 4), np.float32)
    logits[0] = 5.0                                      # water everywhere
    confidence = SolidConfidence(logits, 8, 8)
    confidence.no_picture = np.zeros((8, 8), bool)
    confidence.no_picture[:, :2] = True
    p = confidence.solid_probability(np.array([[0.0, 3.0], [1.4, 7.0], [5.0, 5.0], [-3.0, 1.0]]))
    assert p[0] == p[1] == 1.0 and p[2] < 0.05 and p[3] < 0.05


def _measure(tmp_path: Path, name: str, no_data: np.ndarray | None, masks: bool) -> list[dict]:
    folder = tmp_path / name
    shutil.copytree(SAMPLES, folder, ignore=shutil.ignore_patterns("flight", "instances"))
    for stem in ("000001", "000002", "000003", "000004"):
        for sub, suffix in (("frames", ".json"), ("images", ".png"), ("labels", ".png")):
            (folder / sub / f"{stem}{suffix}").unlink()
    if not masks:
        shutil.rmtree(folder / "labels")
    if no_data is not None:
        image = cv2.imread(str(folder / "images" / "000000.png"))
        cv2.imwrite(str(folder / "images" / "000000.png"), bgra(image, no_data, (0, 0, 0)))
    result = runner.invoke(app, ["measure", str(folder), "--out", str(folder / "out")])
    assert result.exit_code == 0, result.output
    return json.loads((folder / "out" / "000000.json").read_text())["sections"]


@pytest.mark.parametrize("masks", [True, False], ids=["mask file", "model"])
def test_a_band_reaching_the_no_data_corner_stops_there(tmp_path, masks):
    """The sample frame's port side faces open water 10-23 m wide; an orthophoto-like
    transparent corner 40-120 px (4-10 m) from the hull was read as water (the mask
    file's, or the model's on the black fill): clear. Those sections now meet the corner:
    ``ok``, their obstacle point on its edge; the starboard ones, away from it, unchanged."""
    no_data = np.zeros((360, 640), np.uint8)
    cv2.fillPoly(no_data, [np.array([[0, 0], [330, 0], [0, 230]], np.int32)], 1)
    no_data = no_data.astype(bool)
    before = _measure(tmp_path, "opaque", None, masks)
    after = _measure(tmp_path, "transparent", no_data, masks)
    edge_px = cv2.distanceTransform((~no_data).astype(np.uint8), cv2.DIST_L2, 5)
    met = [b for a, b in zip(before, after, strict=True)
           if a["status"] == "clear" and b["status"] == "ok"]
    assert len(met) >= 3
    for section in met:
        u, v = section["obstacle_point_px"]
        assert edge_px[min(round(v), 359), min(round(u), 639)] <= 1.5
        assert section["distance_lower_m"] <= section["distance_m"]
    kept = [(a, b) for a, b in zip(before, after, strict=True) if a["status"] == "ok"
            and a["obstacle_point_px"][0] > 330]
    assert kept and all(a["distance_m"] == pytest.approx(b["distance_m"], abs=0.05)
                        for a, b in kept)


@pytest.mark.parametrize("nodata, expected", [("0", 100), ("255\x00", 6), ("nan", None), ("", None)])
def test_a_geotiff_s_no_data_value_marks_its_pixels(tmp_path, nodata, expected):
    """GDAL writes a raster's no-data value in the TIFF tag 42113 (GDAL_NODATA); a pixel is
    without data where every band holds it (a black pixel of a scene with 0 given is one, as
    GDAL reads it)."""
    from PIL import TiffImagePlugin

    image = np.full((30, 40, 3), 120, np.uint8)
    image[:10, :10] = 0
    image[20, 10:16] = 255
    image[25, 0] = (255, 0, 255)                      # one band off: data
    info = TiffImagePlugin.ImageFileDirectory_v2()
    info[42113] = nodata
    info.tagtype[42113] = 2
    Image.fromarray(image).save(tmp_path / "ortho.tif", tiffinfo=info)
    _, found = read_image_and_no_data(tmp_path / "ortho.tif")
    assert (None if found is None else int(found.sum())) == expected


def test_training_and_evaluation_read_no_data_as_ignore(tmp_path):
    """An imported orthophoto whose annotation's background (water) covers its transparent
    corner: the frame is read black there and labelled 255, as segment and measuring see
    it; training no longer teaches that black is water, and evaluation scores it as ignore."""
    from harborsight.training.dataset import FrameRecord, read_labelled_frame

    image, no_data = picture(), corner(60, 80)
    (tmp_path / "images").mkdir()
    (tmp_path / "labels").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "tile.png"), bgra(image, no_data))
    labels = np.zeros((60, 80), np.uint8)
    labels[40:, 60:] = 1
    cv2.imwrite(str(tmp_path / "labels" / "tile.png"), labels)
    record = FrameRecord(tmp_path, "tile", "train", tmp_path / "images" / "tile.png",
                         tmp_path / "labels" / "tile.png")
    read, read_labels = read_labelled_frame(record)
    assert (read_labels[no_data] == 255).all() and (read[no_data] == 0).all()
    assert np.array_equal(read_labels[~no_data], labels[~no_data])


@pytest.mark.parametrize("suffix", ["png", "tif", "webp"])
@pytest.mark.parametrize("orientation", [2, 3, 6])
def test_the_no_data_pixels_are_turned_as_the_picture(tmp_path, suffix, orientation):
    """A picture stored turned (EXIF or TIFF Orientation): the no-data pixels land where the
    picture shows them. OpenCV turns a PNG's colours but not an alpha read with
    IMREAD_UNCHANGED, and turns a TIFF's bands, alpha too, itself: the first version turned a
    TIFF's alpha twice (picture pixels blacked and counted solid)."""
    image, no_data = picture(), corner(60, 80)
    rgba = bgra(image, no_data, stored=(0, 0, 0))[..., [2, 1, 0, 3]]
    exif = Image.Exif()
    exif[0x0112] = orientation
    path = tmp_path / f"turned.{suffix}"
    Image.fromarray(rgba, "RGBA").save(path, exif=exif, **({"lossless": True} if suffix == "webp" else {}))
    # as displayed, by hand: 2 mirrored, 3 half a turn, 6 a quarter turn clockwise
    turn = {2: np.fliplr, 3: lambda a: np.rot90(a, 2), 6: lambda a: np.rot90(a, -1)}[orientation]
    read, found = read_image_and_no_data(path)
    assert np.array_equal(found, turn(no_data))
    assert np.array_equal(read[~found], turn(image)[~found])


def test_only_a_band_declared_alpha_is_transparency(tmp_path):
    """An RGB + near-infrared TIFF (ExtraSamples 0: not alpha) has NIR near 0 over water: it
    was read as alpha, and the water as a solid wall. Grey images with transparency (grey +
    alpha TIFF, a grey PNG with a transparent key) were missed."""
    rgb, nir = picture(), np.zeros((60, 80), np.uint8)
    nir[:, 40:] = 180
    Image.fromarray(np.dstack([rgb, nir]), "RGBX").save(tmp_path / "rgbn.tif")
    assert read_image_and_no_data(tmp_path / "rgbn.tif")[1] is None
    grey, no_data = picture()[..., 0], corner(60, 80)
    alpha = np.where(no_data, 0, 255).astype(np.uint8)
    Image.fromarray(np.dstack([grey, alpha]), "LA").save(tmp_path / "grey.tif")
    assert np.array_equal(read_image_and_no_data(tmp_path / "grey.tif")[1], no_data)
    keyed = np.where(no_data, 0, np.maximum(grey, 1)).astype(np.uint8)
    Image.fromarray(keyed, "L").save(tmp_path / "keyed.png", transparency=0)
    assert np.array_equal(read_image_and_no_data(tmp_path / "keyed.png")[1], no_data)
